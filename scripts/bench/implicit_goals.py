"""Issue 11 speed goals in one interleaved run (taichi-soft, CPU, f64, serial mode).

usage (from the repository root):  .venv/bin/python scripts/bench/implicit_goals.py [rounds]   (default 3 rounds)
[EXTRA_FMS="global_solver=pcg cg_tol=0.3"] adds one more fast_mass_spring configuration.

The default drop on the plane scene (10^3 cube, 2 s), spring stiffness x10, x100, x1000:

1. the largest stable dt of every explicit method, by ``bench.stability.largest_stable_dt`` with
   ``bench.stability.SceneProbe`` (its criteria: divergence, energy growth > 5 %, penetration
   > 0.1 m within the 2-s drop): halve dt from 0.02 s until a run is stable, then bisect to 2 %;
2. wall seconds per simulated second of the whole drop, explicit methods at 0.9x their own limit,
   implicit_euler and fast_mass_spring at dt = 1/30 s: one untimed warm-up of each, then
   ``rounds`` interleaved rounds (every configuration once per round), ``ti.sync()`` before each
   clock reading; medians (and the CPU time of this process, also medians);
3. the ratio best explicit / best implicit (> 1: implicit faster). Goals: >= 1 at x10, >= 2 at
   x100, >= 5 at x1000.
"""
import math
import os
import statistics
import sys
import time

sys.path.insert(0, os.getcwd())

import taichi as ti  # noqa: E402

from taichi_soft import runtime  # noqa: E402
from taichi_soft.bench import stability  # noqa: E402
from taichi_soft.integrators import REGISTRY  # noqa: E402

SCALES = (10.0, 100.0, 1000.0)
GOALS = {10.0: 1.0, 100.0: 2.0, 1000.0: 5.0}
IMPLICIT_DT = 1.0 / 30.0
HORIZON = 2.0


def base(label: str) -> str:
    """The integrator of a configuration label ("fast_mass_spring [options]" -> "fast_mass_spring")."""
    return label.split(" [")[0]


def main():
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    runtime.init("cpu", "f64")
    t_start = time.perf_counter()
    import platform
    import subprocess
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    cpu = next((line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")),
               platform.processor())
    print(f"checkout {os.getcwd()} at {commit}; {cpu}, {os.cpu_count()} cores; Taichi {'.'.join(map(str, ti.__version__))}, f64, serial mode")
    print(f"load at start (os.getloadavg, 1/5/15 min): {os.getloadavg()}", flush=True)
    explicit = [n for n, c in REGISTRY.items() if not c.implicit]
    implicit = [n for n, c in REGISTRY.items() if c.implicit]
    probes = {n: stability.SceneProbe("plane", n, horizon=HORIZON) for n in explicit + implicit}
    # Optional: one more fast_mass_spring configuration, e.g. EXTRA_FMS="global_solver=pcg cg_tol=0.3".
    extra = os.environ.get("EXTRA_FMS", "").split()
    if extra:
        label = "fast_mass_spring [" + " ".join(extra) + "]"
        probes[label] = stability.SceneProbe("plane", "fast_mass_spring", [f"solver.{o}" for o in extra],
                                             horizon=HORIZON)
        implicit.append(label)

    # 1. explicit limits
    limits = {}
    for scale in SCALES:
        for n in explicit:
            p = probes[n]
            p.set_stiffness_scale(scale)
            hi = 0.02
            while not p(hi / 2) and hi > 1e-5:
                hi /= 2
            lo = hi / 2
            res = stability.largest_stable_dt(p, lo, hi, rel_tol=0.02)
            limits[(scale, n)] = res["dt"]
            print(f"x{scale:g} {n}: largest stable dt {res['dt'] * 1e3:.3f} ms (unstable at {res['bracket'][1] * 1e3:.3f} ms)",
                  flush=True)
    print(f"limits found in {time.perf_counter() - t_start:.0f} s", flush=True)

    # 2. timing
    configs = [(scale, n, 0.9 * limits[(scale, n)]) for scale in SCALES for n in explicit if limits[(scale, n)]]
    configs += [(scale, n, IMPLICIT_DT) for scale in SCALES for n in implicit]
    wall = {c: [] for c in configs}
    cpu = {c: [] for c in configs}
    work = {}

    def run(c):
        scale, n, dt = c
        p = probes[n]
        p.set_stiffness_scale(scale)
        sim = p.sim
        sim.reset()
        sim.set_dt(dt)
        sim.integrator.stats() if hasattr(sim.integrator, "stats") else None
        steps = int(math.ceil(HORIZON / dt))
        ti.sync()
        w0, c0 = time.perf_counter(), time.process_time()
        sim.advance(steps)
        ti.sync()
        w1, c1 = time.perf_counter(), time.process_time()
        assert not sim.diverged, c
        if REGISTRY[base(n)].implicit:
            work[c] = sim.integrator.stats()
        return (w1 - w0) / HORIZON, (c1 - c0) / HORIZON

    for c in configs:  # warm-up (compiles)
        run(c)
    for _ in range(rounds):
        for c in configs:
            w, u = run(c)
            wall[c].append(w)
            cpu[c].append(u)
    med = {c: statistics.median(wall[c]) for c in configs}
    medc = {c: statistics.median(cpu[c]) for c in configs}

    # 3. table
    print()
    print(f"machine: {os.cpu_count()} cores, load average at end {os.getloadavg()}; {rounds} interleaved rounds, "
          f"medians; wall [s] per simulated second of the 2-s drop (cpu [s] of this process in brackets)")
    print()
    print("| stiffness | config | dt [ms] | wall s / sim s | cpu s / sim s | spread (max/min) | work per step |")
    print("|---|---|---|---|---|---|---|")
    for c in configs:
        scale, n, dt = c
        extra = ""
        if c in work:
            s = work[c]
            it = s.get("newton_iterations_per_step", s.get("local_global_iterations_per_step"))
            extra = (f"{it:.2f} it, {s['cg_iterations_per_step']:.1f} CG, clamp {s['energy_clamped_steps']}, "
                     f"res {s['final_residual_m_s2']:.2g} m/s^2")
        print(f"| x{scale:g} | {n} | {dt * 1e3:.3f} | {med[c]:.4f} | {medc[c]:.4f} | {max(wall[c]) / min(wall[c]):.2f} | {extra} |")
    print()
    print("| stiffness | best explicit (0.9x limit) | best implicit (1/30 s) | ratio (wall) | ratio (cpu) | goal | met |")
    print("|---|---|---|---|---|---|---|")
    for scale in SCALES:
        ex = min((c for c in configs if c[0] == scale and not REGISTRY[base(c[1])].implicit), key=med.get)
        im = min((c for c in configs if c[0] == scale and REGISTRY[base(c[1])].implicit), key=med.get)
        r = med[ex] / med[im]
        rc = medc[ex] / medc[im]
        print(f"| x{scale:g} | {ex[1]} {med[ex]:.4f} s | {im[1]} {med[im]:.4f} s | {r:.2f}x | {rc:.2f}x | "
              f">= {GOALS[scale]:g}x | {'yes' if r >= GOALS[scale] else 'NO'} |")
    print("\nratio = best explicit wall time / best implicit wall time (> 1: the implicit solver is faster). Implicit "
          "iterations are averages over all steps of the drop (free-flight steps cost 0); 'res' is the mean final "
          "residual of a step [m/s^2] (0.1 = the solvers' tolerance; fast_mass_spring stops at its iteration cap on "
          "landing steps, see docs/implicit.md, 'Measured results').")
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
