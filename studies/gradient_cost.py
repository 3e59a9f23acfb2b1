"""Cost of one gradient (complex-step pass per parameter) against the engine's forward run."""
import statistics, sys, time
import numpy as np
from taichi_soft import runtime
runtime.init("cpu", "f64")
import taichi as ti
from taichi_soft.sim import Simulation, scene_from_dict
from taichi_soft.sim import gradients
from taichi_soft.sim.simulation import frame_steps

def make(n, duration):
    return Simulation(scene_from_dict({
        "sim": {"integrator": "semi_implicit_euler", "dt": 1e-3, "gravity": [0, -9.8, 0]},
        "body": [{"n": n, "size": 1.0, "particle_mass": 0.5, "center": [0, 0.9, 0],
                  "stretch": {"k": 500.0, "damping": 2.0}, "shear": {"k": 300.0, "damping": 1.0}, "bend": {"k": 200.0, "damping": 1.0}}],
        "terrain": {"kind": "plane", "point": [0, 0, 0], "normal": [0, 1, 0]},
        "contact": {"restitution": 0.5, "friction": 0.3}}))

for n, dur in ((3, 1.0), (5, 1.0), (10, 0.2)):
    sim = make(n, dur)
    steps = frame_steps(int(round(dur / 1e-3)), 30, 1e-3)
    pr = gradients.Problem(sim)
    vals = pr.values()
    t_eng, t_re, t_cx = [], [], []
    for rep in range(4):
        sim.reset(); ti.sync(); t = time.perf_counter(); sim.run(dur, 30, record=True); ti.sync(); t_eng.append(time.perf_counter() - t)
        t = time.perf_counter(); pr.trajectory(vals, steps); t_re.append(time.perf_counter() - t)
        t = time.perf_counter(); pr.trajectory(vals, steps, seed="k_stretch"); t_cx.append(time.perf_counter() - t)
    e, r, c = (statistics.median(a[1:]) for a in (t_eng, t_re, t_cx))
    print(f"n={n} particles={sim.model.n_particles} springs={sim.model.n_springs} duration={dur}s: engine run {e*1e3:.1f} ms, "
          f"numpy real pass {r*1e3:.1f} ms, complex pass (one parameter) {c*1e3:.1f} ms = {c/e:.1f} engine runs; "
          f"per step and particle {c/(dur/1e-3)/sim.model.n_particles*1e6:.2f} us")
