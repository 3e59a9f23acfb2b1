"""A/B of implicit-solver options on the plane scene's default drop (f64, serial, 2 s at dt = DT, default
1/30 s): one simulation per (variant, stiffness scale), a warm-up each, then interleaved rounds; medians.

usage (from the repository root):
  [DT=0.1] .venv/bin/python scripts/bench/ab_options.py "history=0|history=5" 10,100,1000 [rounds] [integrator]
"""
import os, sys, time, statistics
sys.path.insert(0, os.getcwd())
import taichi as ti
from taichi_soft import runtime; runtime.init("cpu", "f64")
from taichi_soft.scene import load_scene
from taichi_soft.simulation import Simulation
from taichi_soft.integrators import names
variants = sys.argv[1].split("|")  # e.g. "history=0|history=5"
scales = [float(s) for s in sys.argv[2].split(",")]
DT = float(os.environ.get("DT", 1 / 30))
rounds = int(sys.argv[3]) if len(sys.argv) > 3 else 5
name = sys.argv[4] if len(sys.argv) > 4 else "fast_mass_spring"
sims = {}
for v in variants:
    for sc in scales:
        opts = [f"solver.{a}" for a in v.split() if a]
        sim = Simulation(load_scene("plane", opts, integrator_names=names()), name, DT)
        sim.model.set_group_stiffness(sim.model.group_k.to_numpy()[: sim.model.n_groups] * sc)
        sim.set_dt(DT)
        sims[(v, sc)] = sim
wall = {k: [] for k in sims}; stats = {}
def run(k):
    sim = sims[k]; sim.reset(); sim.integrator.stats(); ti.sync()
    t = time.perf_counter(); sim.advance(int(round(2 / DT))); ti.sync(); w = time.perf_counter() - t
    stats[k] = sim.integrator.stats(); return w
for k in sims: run(k)
for _ in range(rounds):
    for k in sims: wall[k].append(run(k))
for sc in scales:
    base = None
    for v in variants:
        k = (v, sc); m = statistics.median(wall[k]); base = base or m; s = stats[k]
        it = s.get("local_global_iterations_per_step", s.get("newton_iterations_per_step"))
        print(f"x{sc:g} [{v}] {m/2:.4f} s/sim-s ({base/m:.2f}x first) it/step {it:.2f} res {s['final_residual_m_s2']:.3g} ls {s['line_search_halvings_per_step']:.2f} clamp {s['energy_clamped_steps']} restarts {s.get('lbfgs_restarts_per_step', 0):.2f}")
