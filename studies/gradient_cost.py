"""Cost of one gradient pass (complex step, one parameter) against the engine's forward run
(docs/gradients.md, "Cost and memory")."""
import statistics
import time

from taichi_soft import runtime

runtime.init("cpu", "f64")

import taichi as ti  # noqa: E402

from taichi_soft.sim import Simulation, gradients, scene_from_dict  # noqa: E402
from taichi_soft.sim.simulation import frame_steps  # noqa: E402


def make(n):
    return Simulation(scene_from_dict({
        "sim": {"integrator": "semi_implicit_euler", "dt": 1e-3, "gravity": [0, -9.8, 0]},
        "body": [{"n": n, "size": 1.0, "particle_mass": 0.5, "center": [0, 0.9, 0],
                  "stretch": {"k": 500.0, "damping": 2.0}, "shear": {"k": 300.0, "damping": 1.0},
                  "bend": {"k": 200.0, "damping": 1.0}}],
        "terrain": {"kind": "plane", "point": [0, 0, 0], "normal": [0, 1, 0]},
        "contact": {"restitution": 0.5, "friction": 0.3}}))


def timed(fn):
    ti.sync()
    t = time.perf_counter()
    fn()
    ti.sync()
    return time.perf_counter() - t


for n, dur in ((3, 1.0), (5, 1.0), (10, 0.2)):
    sim = make(n)
    steps = frame_steps(int(round(dur / 1e-3)), 30, 1e-3)
    pr = gradients.Problem(sim)
    vals = pr.values()
    t_eng, t_re, t_cx = [], [], []
    for rep in range(4):  # interleaved; the first of each is the warm-up
        sim.reset()
        t_eng.append(timed(lambda: sim.run(dur, 30, record=True)))
        t_re.append(timed(lambda: pr.trajectory(vals, steps)))
        t_cx.append(timed(lambda: pr.trajectory(vals, steps, seed="k_stretch")))
    e, r, c = (statistics.median(a[1:]) for a in (t_eng, t_re, t_cx))
    print(f"n={n} particles={sim.model.n_particles} springs={sim.model.n_springs} duration={dur}s: "
          f"engine run {e * 1e3:.1f} ms, numpy real pass {r * 1e3:.1f} ms, complex pass {c * 1e3:.1f} ms "
          f"= {c / e:.1f} engine runs")
