"""Issue 23's cost goal: the pile scene at 1/60 s with fast_mass_spring for 4 s, body contact off and
on, every kernel compiled and warmed first, then 3 rounds interleaved (one JSON line: the wall
times [s], the ratio of medians, the deepest overlap [mm] and the contact run's solver counters).

    .venv/bin/python scripts/pile_cost.py [REPOSITORY]   # REPOSITORY: which checkout to import (default: this one)
"""
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, sys.argv[1] if len(sys.argv) > 1 else str(Path(__file__).resolve().parent.parent))
from taichi_soft import runtime  # noqa: E402

runtime.init("cpu", "f64")
import taichi as ti  # noqa: E402

from taichi_soft.sim.integrators import names  # noqa: E402
from taichi_soft.sim.scene import load_scene  # noqa: E402
from taichi_soft.sim.simulation import Simulation  # noqa: E402

sims = {}
for contact in (False, True):
    sc = load_scene("pile", [f"solver.body_contact={'true' if contact else 'false'}"], integrator_names=names())
    sims[contact] = Simulation(sc, integrator="fast_mass_spring", dt=1/60)
    sims[contact].advance(240); ti.sync()  # compile and warm
times = {False: [], True: []}
stats = {}
for r in range(3):
    for contact in ((False, True) if r % 2 == 0 else (True, False)):
        sim = sims[contact]; sim.reset(); sim.integrator.stats(); ti.sync()
        t = time.perf_counter(); sim.advance(240); ti.sync(); times[contact].append(time.perf_counter() - t)
        stats[contact] = sim.integrator.stats()
off, on = statistics.median(times[False]), statistics.median(times[True])
s = stats[True]
print(json.dumps({"off_s": times[False], "on_s": times[True], "ratio": on / off, "deepest_mm": s.get("body_deepest_overlap_m", 0) * 1e3,
                  "cg_per_step": s.get("cg_iterations_per_step"), "clamped": s.get("energy_clamped_steps"), "failed": s.get("failed_solve_steps"),
                  "unconverged": s.get("unconverged_steps")}))
