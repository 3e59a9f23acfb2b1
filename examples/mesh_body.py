"""Drop a soft torus cut from a triangle mesh (scenes/meshes/torus.obj) flat onto the ground plane
and watch it come to rest on it, from Python.

    python examples/mesh_body.py

A mesh body is a lattice clipped to a closed mesh (OBJ, STL or PLY): ``n`` lattice points along
the mesh's longest side, which is ``size`` metres long (docs/scenes.md, ``shape = "mesh"``).
"""
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # a checkout needs no pip install

import numpy as np  # noqa: E402

from taichi_soft import runtime  # noqa: E402
from taichi_soft.sim import BodySpec, Simulation  # noqa: E402

runtime.init("cpu", "f64")
torus = BodySpec(shape="mesh", mesh=str(ROOT / "scenes" / "meshes" / "torus.obj"), n=12, size=2.0,
                 center=(0.0, 1.0, 0.0), rotation_axis=(1.0, 0.0, 0.0), rotation_degrees=90.0)  # lying flat
plane = {"kind": "plane", "point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0]}  # the ground y = 0
sim = Simulation.from_parts([torus], terrain=plane, integrator="semi_implicit_euler", dt=1e-3,
                            restitution=0.0, friction=0.5)
x0 = sim.state.x.to_numpy()
print(f"{sim.model.n_particles} particles, {sim.model.n_springs} springs; "
      f"half height {x0[:, 1].mean() - x0[:, 1].min():.4f} m")
result = sim.run(duration=2.0, fps=10, record=True)
if result.diverged:
    sys.exit(f"diverged at t = {result.diverged_at:.3f} s: try a smaller dt")
for t, x, v in result.frames[::4]:
    speed = np.linalg.norm(v, axis=1).max()
    print(f"t = {t:4.2f} s   lowest point y = {x[:, 1].min():+.4f} m   centre y = {x[:, 1].mean():+.4f} m   "
          f"fastest particle {speed:.4f} m/s")
