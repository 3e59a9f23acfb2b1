"""Iterations and time of an implicit solver over five drops (the plane scene's default cube at initial
rotations of 10, 25, 30, 40 and 55 degrees, 2 s at dt = 1/30 s, f64, serial): one drop is chaotic
(a small change at the landing changes whether the cube bounces), five compare options fairly.

usage (from the repository root):
  [NAME=implicit_euler] [SCENE=bowl] [N=15] .venv/bin/python scripts/bench/drops_rotations.py 10,100 [solver options, e.g. history=0]
"""
import os, sys, time
sys.path.insert(0, os.getcwd())
import taichi as ti
from taichi_soft import runtime; runtime.init("cpu", "f64")
from taichi_soft.scene import load_scene
from taichi_soft.simulation import Simulation
from taichi_soft.integrators import names
NAME = os.environ.get("NAME", "fast_mass_spring")
SCENE = os.environ.get("SCENE", "plane")
EXTRA = [f"body.0.n={os.environ['N']}"] if "N" in os.environ else []
scales = [float(s) for s in sys.argv[1].split(",")]
opts = [a if a.startswith("contact.") else "solver." + a for a in sys.argv[2:]]
angles = (10.0, 25.0, 30.0, 40.0, 55.0)
for sc in scales:
    tot_it = tot_t = tot_res = tot_cg = 0.0; cl = 0
    for ang in angles:
        sim = Simulation(load_scene(SCENE, opts + EXTRA + [f"body.0.rotation.degrees={ang}"], integrator_names=names()), NAME, 1/30)
        sim.model.set_group_stiffness(sim.model.group_k.to_numpy()[: sim.model.n_groups] * sc)
        sim.set_dt(1/30)
        best = 1e9
        for rep in range(2):
            sim.reset(); sim.integrator.stats(); ti.sync(); t = time.perf_counter(); sim.advance(60); ti.sync(); best = min(best, time.perf_counter() - t)
            s = sim.integrator.stats()
        tot_cg += s["cg_iterations_per_step"] * 60; tot_it += s.get("local_global_iterations_per_step", s.get("newton_iterations_per_step")) * 60; tot_t += best; tot_res += s["final_residual_m_s2"]; cl += s["energy_clamped_steps"]
    print(f"x{sc:g} CG {tot_cg:.0f} {' '.join(sys.argv[2:])}: iterations {tot_it:.0f} over {len(angles)} drops, time {tot_t:.3f} s (best of 2 each), mean residual {tot_res/len(angles):.3g}, clamps {cl}")
