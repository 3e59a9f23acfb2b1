"""Why the engine's gather was slower than a plain Taichi kernel: one change at a time.

    python -m studies.kernel_study [--n 40] [--precision f32] [--no-fast-math] [--threads 1]

Times, in one process and interleaved (one repeat of each in turn, medians), semi-implicit Euler
steps of the same stretched n^3 cube (no terrain) with gather kernels that differ in one thing:

* ``yardstick``: the plain kernel of the yardstick taichi_ref.py (outside this repository; re-implemented here) --mode gather --perspring
  (CSR rows, ``d / length``, no zero-length guard, k and kd per entry);
* ``csr_branch``: the engine's old spring loop: ``if length > 0`` around the force (CSR rows);
* ``csr``: the same without the branch (``length + TINY``, forces.spring_force);
* ``rows``: padded rows of constant length (rows.py), the engine's loop;
* ``rows_lookup``: the same, k and kd looked up through the spring group per slot;
* ``rows_table``: the same rows with 8 bytes a slot instead of 16: the other end and a kind, which
  indexes a small table of (rest, k, kd), one per distinct (group, rest length) of the slots;
* ``lookup_fields``: the same, with what the engine reads at run time read as it does: dt a kernel
  argument, gravity from its field, 1/m per particle (``rows_lookup`` bakes all three in);
* ``lookup_check``: the same plus the engine's divergence check per particle (bits of |v|^2 and
  an atomic on a flag);
* ``rows_check``: ``rows`` (per-slot copies) with the engine's run-time reads and check: the
  engine's step written out in one kernel;
* the engine itself (``engine gather``, ``engine scatter``) through ``Simulation.advance``.

Prints steps per second of wall time and of CPU time (the steadier measure on a shared machine)
and each ratio to the yardstick. docs/benchmarks/README.md, "Speed: why the engine was slower", has the
results and the generated code behind them (``ti.init(print_kernel_asm=True)``).
"""

import argparse
import os

import numpy as np

from taichi_soft.timing import Candidate, time_candidates

VARIANTS = ("yardstick", "csr_branch", "csr", "rows", "rows_lookup", "rows_table", "lookup_fields", "lookup_check", "rows_check")


def _kernels(sim):
    """{variant: step(xo, vo, xn, vn)} on the simulation's model, plus its helper fields."""
    import taichi as ti

    from taichi_soft.sim.forces import spring_force
    from taichi_soft.sim.integrators.base import _not_finite
    from taichi_soft.sim.rows import SpringRows

    m = sim.model
    m.ensure_adjacency()
    rows = SpringRows(m)
    e = 2 * m.n_springs
    group = m.adj_group.to_numpy()[:e]
    k_np, kd_np = m.group_k.to_numpy(), m.group_kd.to_numpy()
    k_e, kd_e = ti.field(float, e), ti.field(float, e)
    k_e.from_numpy(k_np[group])
    kd_e.from_numpy(kd_np[group])
    w = rows.width
    slot_group = rows.group.to_numpy()
    rows.kkd.from_numpy(np.stack([k_np[slot_group], kd_np[slot_group]], axis=1))
    # slot kinds: each distinct (group, rest) of the slots indexes a small table of (rest, k, kd)
    slot_rest = rows.rest.to_numpy()
    pairs = np.stack([slot_group.astype(np.float64), slot_rest.astype(np.float64)], axis=1)
    uniq, kind_np = np.unique(pairs, axis=0, return_inverse=True)
    table = ti.Vector.field(4, float, len(uniq))
    tg = uniq[:, 0].astype(int)
    table.from_numpy(np.stack([uniq[:, 1], k_np[tg], kd_np[tg], np.zeros(len(uniq))], axis=1).astype(slot_rest.dtype))
    kind = ti.field(ti.i32, len(kind_np))
    kind.from_numpy(kind_np.astype(np.int32).ravel())
    dt, inv_m = sim.dt, 1.0 / float(m.mass_np[0])
    limit, flag = ti.field(float, ()), ti.field(ti.i32, ())
    limit[None], flag[None] = 1e12, 1
    g = tuple(float(c) for c in m.gravity[None].to_numpy())

    def make(variant):
        @ti.kernel
        def step(xo: ti.template(), vo: ti.template(), xn: ti.template(), vn: ti.template(), h: float):
            for i in range(m.n_particles):
                xi, vi = xo[i], vo[i]
                f = ti.Vector.zero(float, 3)
                if ti.static(variant.startswith("rows") or variant.startswith("lookup")):
                    for s in range(w):
                        slot = i * w + s
                        j = rows.other[slot]
                        d = xi - xo[j]
                        kkd = ti.Vector.zero(float, 2)
                        rest = rows.rest[slot]
                        if ti.static(variant == "rows_table"):
                            t = table[kind[slot]]
                            rest = t[0]
                            kkd = ti.Vector([t[1], t[2]])
                        elif ti.static(variant not in ("rows", "rows_check")):
                            kkd = ti.Vector([m.group_k[rows.group[slot]], m.group_kd[rows.group[slot]]])
                        else:
                            kkd = rows.kkd[slot]
                        f += spring_force(d, vi - vo[j], d.norm(), rest, kkd[0], kkd[1])
                else:
                    for a in range(m.adj_offset[i], m.adj_offset[i + 1]):
                        j = m.adj_other[a]
                        d = xi - xo[j]
                        length = d.norm()
                        if ti.static(variant == "yardstick"):
                            lh = d / length
                            f += -k_e[a] * (length - m.adj_rest[a]) * lh - kd_e[a] * (vi - vo[j]).dot(lh) * lh
                        elif ti.static(variant == "csr_branch"):
                            if length > 0:
                                lh = d * (1.0 / length)
                                f -= (k_e[a] * (length - m.adj_rest[a]) + kd_e[a] * (vi - vo[j]).dot(lh)) * lh
                        else:
                            f += spring_force(d, vi - vo[j], length, m.adj_rest[a], k_e[a], kd_e[a])
                if ti.static(variant.startswith("lookup") or variant == "rows_check"):
                    a = m.gravity[None] * ti.cast(m.inv_mass[i] > 0, float) + f * m.inv_mass[i]
                    v_new = vi + h * a
                    vn[i] = v_new
                    xn[i] = xi + h * v_new
                    if ti.static(variant.endswith("_check")):
                        speed2 = v_new.dot(v_new)
                        if _not_finite(speed2) or speed2 > limit[None]:
                            ti.atomic_min(flag[None], 0)
                else:
                    v_new = vi + dt * (f * inv_m + ti.Vector(g))
                    vn[i] = v_new
                    xn[i] = xi + dt * v_new

        return step

    return {v: make(v) for v in VARIANTS}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=40)
    p.add_argument("--precision", default="f32", choices=("f32", "f64"))
    p.add_argument("--no-fast-math", action="store_true")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--rounds", type=int, default=7)
    p.add_argument("--free-threads", action="store_true", help="leave Taichi's pool workers unpinned (cpu_threads.py)")
    a = p.parse_args(argv)
    from taichi_soft import runtime

    runtime.init("cpu", a.precision, fast_math=not a.no_fast_math, cpu_max_num_threads=a.threads,
                 pin_threads=not a.free_threads)
    from taichi_soft.workarounds import cpu_threads

    cpu_threads.place(True)  # every kernel here is an explicit step: pinned from the first (unless --free-threads)
    import taichi as ti

    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import Simulation
    from taichi_soft.bench.speed_worker import REFERENCE_SCENE

    def sim_for(forces):
        scene = load_scene("plane", [f"body.0.n={a.n}", *REFERENCE_SCENE])
        return Simulation(scene, integrator="semi_implicit_euler", options={"forces": forces, "mode": "parallel"})

    base = sim_for("gather")
    kernels = _kernels(base)
    x2 = ti.Vector.field(3, float, base.model.n_particles)
    v2 = ti.Vector.field(3, float, base.model.n_particles)

    def stepper(kernel):
        def advance(k):
            st = base.state
            for s in range(k):
                if s % 2 == 0:
                    kernel(st.x, st.v, x2, v2, base.dt)
                else:
                    kernel(x2, v2, st.x, st.v, base.dt)
        return base.reset, advance

    runs = {name: stepper(kern) for name, kern in kernels.items()}
    for forces in ("gather", "scatter"):
        sim = sim_for(forces)
        runs[f"engine {forces}"] = (sim.reset, sim.advance)
    chunk = max(4, int(2e7 / (a.n ** 3 * 13)) // 2 * 2)
    # interleaved, order rotated each round; medians of wall and CPU seconds
    timings = time_candidates({name: Candidate(lambda adv=advance: adv(chunk), setup=reset,
                                               warmup=lambda adv=advance: adv(2))
                               for name, (reset, advance) in runs.items()}, a.rounds)
    names = list(runs)
    print(f"n = {a.n}, {a.precision}, fast math {'off' if a.no_fast_math else 'on'}, {a.threads} thread(s), "
          f"{chunk} steps x {a.rounds} rounds, load {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    ref_w = chunk / timings["yardstick"].median
    ref_c = chunk / timings["yardstick"].cpu_median
    print(f"{'kernel':18s} {'steps/s':>9s} {'steps/CPU s':>12s} {'/ yardstick (wall, CPU)':>26s}")
    for name in names:
        w, c = chunk / timings[name].median, chunk / timings[name].cpu_median
        print(f"{name:18s} {w:9.1f} {c:12.1f} {w / ref_w:12.2f} {c / ref_c:12.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
