"""A small cube sliding on a wide one (implicit solvers at 1/60 s, semi-implicit Euler at 1/960 s):
the relative deceleration against mu g (issue 23's sliding test, not met; docs/implicit.md,
"Contact between bodies").

The lower body is a 3 m cube (n = 10) resting on the plane, the upper a 1 m cube (n = 4, the same
lattice spacing, 1/3 m) resting on it at one lattice spacing (the contact distance) with 1.5 m/s
along x. The plane's friction is the pairs' (one ``contact.friction``); the plane carries the
whole load, so it holds the lower cube. Prints, per solver and mu, the relative x velocity of the
two centres of mass every 3 samples (1/60 s apart) and the deceleration fitted over 0.05-0.3 s [m/s^2].

    TAICHI_SOFT_OPTIMIZE=0 .venv/bin/python scripts/body_slide.py
"""
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from taichi_soft import runtime  # noqa: E402

runtime.init("cpu", "f64")

from taichi_soft.sim.integrators import names  # noqa: E402
from taichi_soft.sim.lattice import lattice_points  # noqa: E402
from taichi_soft.sim.scene import load_scene  # noqa: E402
from taichi_soft.sim.simulation import Simulation  # noqa: E402

G, V0, DT = 9.8, 1.5, 1 / 60  # DT: the implicit solvers' step and the sampling interval [s]
UPPER, LOWER = (4, 1.0), (10, 3.0)  # (n, size [m]): the same spacing
SPACING = UPPER[1] / (UPPER[0] - 1)


def slide(name: str, mu: float, dt: float) -> dict:
    sets = [f"body.0.n={LOWER[0]}", f"body.0.size={LOWER[1]}", f"body.1.n={UPPER[0]}", f"body.1.size={UPPER[1]}",
            f"contact.friction={mu}"]
    with tempfile.TemporaryDirectory() as folder:
        scene = Path(folder) / "two.toml"
        scene.write_text("[[body]]\n[[body]]\ncenter = [0, 5, 0]\n[terrain]\nkind = \"plane\"\npoint = [0, 0, 0]\n")
        data = load_scene(str(scene), sets, integrator_names=names())
    sim = Simulation(data, integrator=name, dt=dt)
    low, high = (b.particles for b in sim.model.bodies)
    x = np.concatenate([lattice_points(*LOWER) + [0, LOWER[1] / 2, 0],
                        lattice_points(*UPPER) + [-UPPER[1], LOWER[1] + UPPER[1] / 2 + SPACING, 0]])
    v = np.zeros_like(x)
    v[high] = [V0, 0, 0]
    sim.state.set(x, v)
    sim.terrain.reset(sim.state.x)
    t, rel = [], []
    for k in range(36):
        sim.advance(int(round(DT / dt)))
        vv = sim.state.numpy()[1]
        t.append((k + 1) * DT)
        rel.append(vv[high, 0].mean() - vv[low, 0].mean())
    t, rel = np.array(t), np.array(rel)
    fit = (t >= 0.05) & (t <= 0.3)
    return {"solver": name, "dt": round(dt, 6), "mu": mu, "mu_g": mu * G, "deceleration": -float(np.polyfit(t[fit], rel[fit], 1)[0]),
            "relative_vx_every_0.05_s": [round(float(r), 3) for r in rel[::3]]}


def main():
    runs = (("implicit_euler", DT), ("fast_mass_spring", DT), ("semi_implicit_euler", DT / 16))
    for name, dt in runs:
        for mu in (0.0, 0.3):
            print(json.dumps(slide(name, mu, dt)), flush=True)


if __name__ == "__main__":
    main()
