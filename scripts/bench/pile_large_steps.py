"""Issue 23: the pile scene at large steps, both implicit solvers, through the energy matrix's rows.

Per (solver, dt): the energy matrix's row (``bench energy``: rise of the total energy above its
running minimum over max |E|, deepest overlap between bodies at any step [m], candidate pairs left
out of the list), plus the candidate pairs per step (and the most in one list), the lists rebuilt per step, the trials
rejected outside the pair list's tube and the wall seconds
of the 3-s run (the simulation built and compiled by a warm-up step first; ``ti.sync()`` before each
clock reading).
usage (from the repository root): .venv/bin/python scripts/bench/pile_large_steps.py [DT ...] [--solver NAME]"""
import os
import sys
import time

sys.path.insert(0, os.getcwd())
import taichi as ti  # noqa: E402

from taichi_soft import runtime  # noqa: E402

runtime.init("cpu", "f64")
from taichi_soft.bench import energy  # noqa: E402

args = sys.argv[1:]
solvers = energy.SOLVERS
if "--solver" in args:
    k = args.index("--solver")
    solvers = (args[k + 1],)
    del args[k:k + 2]
steps = [float(eval(a)) for a in args] or [0.1, 1 / 60]
sims = {}
for solver in solvers:
    for dt in steps:
        case = {"solver": solver, "scene": "pile", "sets": [], "stiffness_scale": 1.0, "dt": dt, "horizon": 3.0}
        sim, _k = energy._simulation(case, sims)
        sim.set_dt(dt)
        sim.advance(1)  # compile
        last = {}
        if not hasattr(sim.integrator, "_probe_stats"):
            sim.integrator._probe_stats = sim.integrator.stats

            def stats(integ=sim.integrator, last=last):
                last.clear()
                last.update(integ._probe_stats())
                return dict(last)
            sim.integrator.stats = stats
        ti.sync()
        t0 = time.perf_counter()
        row = energy.run_case(case, sims)
        ti.sync()
        wall = time.perf_counter() - t0
        s = dict(sim.integrator.stats.__defaults__[1])  # the run's counters, as run_case read them
        print(f"{solver:16s} dt {dt:.4g}: rise {row['rise']:.2e} clean {row['clean']} overlap "
              f"{row['deepest_overlap_m']:.3g} m dropped {row['pairs_dropped']} clamps {row['energy_clamped_steps']} "
              f"failed {row['failed_solve_steps']} candidates/step {s.get('body_candidate_pairs_per_step', 0):.0f} most "
              f"{s.get('body_candidate_pairs_most', '-')} lists rebuilt/step {s.get('body_pair_lists_rebuilt_per_step', 0):.2f} "
              f"trust rejections {s.get('body_trust_region_rejections', 0)} wall {wall:.1f} s (with the energy per step)",
              flush=True)
