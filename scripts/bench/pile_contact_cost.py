"""Issue 23 goal: the pile scene at 1/60 s with fast_mass_spring, body contact on against off.

Per frame (1/30 s) the deepest overlap between particles of different bodies, as a fraction of the
smaller lattice spacing of the pair; wall seconds of the whole 6-s run with body-body contact inside
the step (``solver.body_contact = true``) and without (bodies pass through each other): a warm-up
step of each, then ROUNDS interleaved rounds, ``ti.sync()`` before each clock reading, medians.
usage (from the repository root): .venv/bin/python scripts/bench/pile_contact_cost.py [INTEGRATOR] [DT] [ROUNDS] [KEY=VALUE ...]
(KEY=VALUE: scene overrides for both runs, as --set)"""
import os, sys, time, json
sys.path.insert(0, os.getcwd())
import numpy as np
import taichi as ti
from taichi_soft import runtime; runtime.init("cpu", "f64")
from taichi_soft.scene import load_scene
from taichi_soft.simulation import Simulation
from taichi_soft.integrators import names
from taichi_soft.collision import contact_radii

name = sys.argv[1] if len(sys.argv) > 1 else "fast_mass_spring"
dt = float(eval(sys.argv[2])) if len(sys.argv) > 2 else 1 / 60
rounds = int(sys.argv[3]) if len(sys.argv) > 3 else 1
sets = sys.argv[4:]
sims = {on: Simulation(load_scene("pile", sets + [f"solver.body_contact={'true' if on else 'false'}"], integrator_names=names()),
                       name, dt) for on in (True, False)}
sim = sims[True]
r = contact_radii(sim.model)
body = np.zeros(sim.model.n_particles, int)
for b, info in enumerate(sim.model.bodies):
    body[info.particles] = b
duration = sim.scene.sim["duration"]
frame = max(1, int(round((1 / 30) / dt)))
n_frames = int(round(duration / dt)) // frame


def deepest(x):
    ov = (r[:, None] + r[None, :]) - np.linalg.norm(x[:, None] - x[None, :], axis=2)
    ov[body[:, None] == body[None, :]] = -np.inf
    i, j = np.unravel_index(ov.argmax(), ov.shape)
    return ov[i, j] / (2 * min(r[i], r[j]))


for s in sims.values():  # warm-up: compile
    s.advance(1); ti.sync(); s.reset(); s.integrator.stats()
walls = {True: [], False: []}
worst, stats = 0.0, {}
for k in range(rounds):
    for on in (True, False):
        s = sims[on]
        s.reset(); s.integrator.stats()
        wall = 0.0
        for _ in range(n_frames):
            ti.sync(); t0 = time.perf_counter()
            s.advance(frame); ti.sync()
            wall += time.perf_counter() - t0
            if on:
                worst = max(worst, deepest(s.state.numpy()[0]))
        walls[on].append(wall)
        stats[on] = s.integrator.stats()
        assert not s.diverged, f"diverged (body_contact={on})"
on, off = np.median(walls[True]), np.median(walls[False])
print(json.dumps({"integrator": name, "dt": dt, "sets": sets, "particles": sim.model.n_particles, "rounds": rounds,
                  "deepest_overlap_fraction_of_spacing": worst, "wall_on_s": on, "wall_off_s": off, "ratio": on / off,
                  "walls": {str(k): v for k, v in walls.items()}, "load": os.getloadavg(),
                  "stats_on": stats[True], "stats_off": stats[False]}, indent=1))
