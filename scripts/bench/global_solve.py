"""Issue 11: fast_mass_spring's global solve three ways on the same matrix (default 10^3 cube, dt=1/30 s, x1, f64, CPU):
the skyline Cholesky (serial, in a kernel), ti.linalg.SparseSolver (LLT, one solve per coordinate from Python), and
Jacobi PCG (matrix-free, to relative residual 0.1 and 1e-8). One solve of A X = B (three right-hand sides). Warm-up,
then interleaved rounds; medians. usage (from the repository root): .venv/bin/python scripts/bench/global_solve.py [rounds]"""
import os, sys, time, statistics, platform
sys.path.insert(0, os.getcwd())
import numpy as np
import taichi as ti
from taichi_soft import runtime; runtime.init("cpu", "f64")
from taichi_soft.scene import load_scene
from taichi_soft.simulation import Simulation
from taichi_soft.integrators import names

rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 7
REPS = 10
sim = Simulation(load_scene("plane", [], integrator_names=names()), "fast_mass_spring", 1 / 30)
sim.set_dt(1 / 30)
it = sim.integrator
it._prepare(1 / 30)
n = sim.model.n_particles
rng = np.random.default_rng(1)
B = rng.standard_normal((n, 3))
b_field = ti.Vector.field(3, float, n); b_field.from_numpy(B)
x_field = ti.Vector.field(3, float, n)

# The same matrix A = M + L assembled for SparseSolver from the integrator's own fields.
pairs = sim.model.pairs_np
c = it.group_c.to_numpy()[sim.model.group_np]
diag = it.diag.to_numpy()
import collections
rows = np.concatenate([np.arange(n), pairs[:, 0], pairs[:, 1]])
cols = np.concatenate([np.arange(n), pairs[:, 1], pairs[:, 0]])
vals = np.concatenate([diag, -c, -c])
trip = len(rows)
builder = ti.linalg.SparseMatrixBuilder(n, n, max_num_triplets=trip, dtype=ti.f64)
r_nd = ti.ndarray(ti.i32, trip); c_nd = ti.ndarray(ti.i32, trip); v_nd = ti.ndarray(ti.f64, trip)
r_nd.from_numpy(rows.astype(np.int32)); c_nd.from_numpy(cols.astype(np.int32)); v_nd.from_numpy(vals)

@ti.kernel
def fill(K: ti.types.sparse_matrix_builder(), r: ti.types.ndarray(), cc: ti.types.ndarray(), v: ti.types.ndarray()):
    for k in range(trip):
        K[r[k], cc[k]] += v[k]

fill(builder, r_nd, c_nd, v_nd)
A = builder.build()
t0 = time.perf_counter()
solver = ti.linalg.SparseSolver(solver_type="LLT", dtype=ti.f64)
solver.analyze_pattern(A); solver.factorize(A)
t_fact_sparse = time.perf_counter() - t0
it._k_assemble(); ti.sync(); t0 = time.perf_counter(); it.chol.factor(); ti.sync(); t_fact_sky = time.perf_counter() - t0
b_nd = [ti.ndarray(ti.f64, n) for _ in range(3)]
for d in range(3):
    b_nd[d].from_numpy(np.ascontiguousarray(B[:, d]))

def skyline(out=True):
    it.chol.solve_kernel(b_field, x_field); ti.sync()
    return x_field.to_numpy() if out else None

def sparse(out=True):
    res = [solver.solve(b_nd[d]) for d in range(3)]
    ti.sync()
    if not out:
        return None
    return np.stack([o.to_numpy() if hasattr(o, "to_numpy") else np.asarray(o) for o in res], axis=1)

# PCG on the same matrix: the global_solver = "pcg" integrator (Jacobi preconditioner, A applied
# matrix-free); no particle held, so its operator is A exactly.
sim_pcg = Simulation(load_scene("plane", ["solver.global_solver=pcg"], integrator_names=names()), "fast_mass_spring", 1 / 30)
ip = sim_pcg.integrator
ip._prepare(1 / 30)
@ti.kernel
def no_contact():
    for i in range(n):
        ip.active[i] = 0
        ip.fric_hess[i] = ti.Matrix.zero(float, 3, 3)
no_contact()
def pcg(tol):
    def run(out=True):
        ip.pcg.rel_tol[None] = tol
        x_field.fill(0)
        k = ip.pcg.solve_parallel(ip, b_field, x_field, 10000)
        ti.sync()
        run.iters = k
        return x_field.to_numpy() if out else None
    return run
cases = {"skyline Cholesky (kernel)": skyline, "SparseSolver LLT (3 solves)": sparse,
         "Jacobi PCG to 0.1": pcg(0.1), "Jacobi PCG to 1e-8": pcg(1e-8)}
ref = skyline()
Adense = None
times = {k: [] for k in cases}
for k, f in cases.items():
    x = f()
    err = np.abs(x - ref).max() / np.abs(ref).max()
    print(f"{k}: max relative difference from the skyline solution {err:.2e}" + (f", {f.iters} iterations" if hasattr(f, "iters") else ""))
for _ in range(rounds):
    for k, f in cases.items():
        t0 = time.perf_counter()
        for _ in range(REPS):
            f(False)
        times[k].append((time.perf_counter() - t0) / REPS)
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.processor())
print(f"\n{cpu}, {os.cpu_count()} cores, load {os.getloadavg()}; {rounds} interleaved rounds of {REPS}, medians")
print("| solve A X = B (n = 1000, three right-hand sides) | ms |\n|---|---|")
for k in cases:
    print(f"| {k} | {statistics.median(times[k]) * 1e3:.3f} |")
print(f"factorisation: skyline {t_fact_sky * 1e3:.0f} ms, SparseSolver analyze+factorize {t_fact_sparse * 1e3:.0f} ms")
