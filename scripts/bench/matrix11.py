"""Issue 11 energy matrix: both implicit solvers x 4 terrains x stiffness x1..x1000 x dt in {1/60, 1/30, 0.1} s,
the default cube's 3-s drop with the contact defaults. Per case: total energy never above its running minimum
(beyond 1e-9 relative), penetration, divergence, energy clamps. Then the two-body cases (issue 23): both solvers x
the scenes three_cubes (plane) and pile (bowl) at their own stiffnesses x dt in {1/60, 1/30, 0.1} s, 3 s, the total
energy counting the body-body contact penalty (pairs.py), and the deepest overlap between bodies.
usage (from the repository root): .venv/bin/python scripts/bench/matrix11.py [--bodies-only]"""
import os, sys, time
sys.path.insert(0, os.getcwd())
sys.path.insert(0, os.path.join(os.getcwd(), "tests"))
import numpy as np
from taichi_soft import runtime; runtime.init("cpu", "f64")
from taichi_soft.scene import load_scene
from taichi_soft.simulation import Simulation
from taichi_soft.integrators import names
from physics_helpers import total_energy
from taichi_soft.collision import contact_radii


def pair_energy(sim, x, dt):
    """Body-body penalty energy [J] at x (pairs.py: kappa m_ij / (2 h^2) o^2 per overlapping pair) and the
    deepest overlap [m]."""
    m, r = sim.model.mass_np, contact_radii(sim.model)
    body = np.zeros(len(m), int)
    for b, info in enumerate(sim.model.bodies):
        body[info.particles] = b
    ov = (r[:, None] + r[None, :]) - np.linalg.norm(x[:, None] - x[None, :], axis=2)
    ov[body[:, None] >= body[None, :]] = 0.0
    ov = np.maximum(ov, 0.0)
    mij = m[:, None] * m[None, :] / (m[:, None] + m[None, :])
    kappa = sim.integrator.options["contact_stiffness"]
    return float(np.sum(0.5 * kappa * mij * ov * ov) / dt ** 2), float(ov.max())

t0 = time.time()
ok = bad = 0
clamped = total_steps = 0
notes = []
deepest = 0.0
BODIES_ONLY = "--bodies-only" in sys.argv[1:]
for name in ("implicit_euler", "fast_mass_spring"):
    for terrain in () if BODIES_ONLY else ("plane", "tilted_plane", "sphere", "bowl"):
        sim = Simulation(load_scene(terrain, integrator_names=names()), name, 1 / 60)
        for scale in (1.0, 10.0, 100.0, 1000.0):
            for kind in ("stretch", "shear", "bend"):
                sim.model.set_spring_params(0, kind, k=2000.0 * scale)
            for dt in (1 / 60, 1 / 30, 0.1):
                sim.set_dt(dt); sim.reset(); sim.integrator.stats()
                steps = int(round(3.0 / dt))
                e = [total_energy(sim.model, *sim.state.numpy())]
                div = False
                for _ in range(steps):
                    sim.advance(1)
                    if sim.diverged:
                        div = True; break
                    deepest = min(deepest, sim.measure()["min_terrain_distance"])
                    e.append(total_energy(sim.model, *sim.state.numpy()))
                e = np.array(e)
                rise = (e[1:] - np.minimum.accumulate(e)[:-1]).max() / np.abs(e).max()
                s = sim.integrator.stats()
                clamped += s["energy_clamped_steps"]; total_steps += s["steps"]
                good = (not div) and rise <= 1e-9
                ok += good; bad += not good
                if not good or s["energy_clamped_steps"]:
                    notes.append(f"{name} {terrain} x{scale:g} dt={dt:.4f}: rise {rise:.2e} diverged {div} clamps {s['energy_clamped_steps']}/{s['steps']}")
                print(f"{name:16s} {terrain:12s} x{scale:<5g} dt={dt:.4f}: rise/max|E| {rise:9.2e} clamps {s['energy_clamped_steps']}/{s['steps']}"
                      f"{' DIVERGED' if div else ''}", flush=True)
overlap = 0.0
for name in ("implicit_euler", "fast_mass_spring"):
    for scene in ("three_cubes", "pile"):
        sim = Simulation(load_scene(scene, integrator_names=names()), name, 1 / 60)
        for dt in (1 / 60, 1 / 30, 0.1):
            sim.set_dt(dt); sim.reset(); sim.integrator.stats()

            def energy():
                x, v = sim.state.numpy()
                ep, deep = pair_energy(sim, x, dt)
                return total_energy(sim.model, x, v) + ep, deep

            e0, _ = energy()
            e, div, deep_case = [e0], False, 0.0
            for _ in range(int(round(3.0 / dt))):
                sim.advance(1)
                if sim.diverged:
                    div = True; break
                ek, deep = energy()
                e.append(ek); deep_case = max(deep_case, deep)
            e = np.array(e)
            rise = (e[1:] - np.minimum.accumulate(e)[:-1]).max() / np.abs(e).max()
            s = sim.integrator.stats()
            clamped += s["energy_clamped_steps"]; total_steps += s["steps"]
            overlap = max(overlap, deep_case)
            good = (not div) and rise <= 1e-9
            ok += good; bad += not good
            if not good or s["energy_clamped_steps"]:
                notes.append(f"{name} {scene} dt={dt:.4f}: rise {rise:.2e} diverged {div} clamps {s['energy_clamped_steps']}/{s['steps']}")
            print(f"{name:16s} {scene:12s} dt={dt:.4f}: rise/max|E| {rise:9.2e} clamps {s['energy_clamped_steps']}/{s['steps']} "
                  f"deepest overlap {deep_case:.2e} m{' DIVERGED' if div else ''}", flush=True)
print(f"\n{ok} of {ok + bad} cases with no rise above the running minimum beyond 1e-9 relative; "
      f"clamp on {clamped} of {total_steps} steps; deepest particle {-deepest:.2e} m inside; "
      f"deepest overlap between bodies {overlap:.2e} m; {time.time() - t0:.0f} s")
for n in notes:
    print(" ", n)
