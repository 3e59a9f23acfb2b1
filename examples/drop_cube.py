"""Drop a soft cube on the ground plane, from Python, and print where it lands.

    python examples/drop_cube.py

The scene is a dict with the keys of a scene file (docs/scenes.md); ``scene_from_dict``
validates it exactly as ``load_scene`` validates a TOML file.
"""
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # a checkout needs no pip install

from taichi_soft import runtime  # noqa: E402

from taichi_soft.sim import Simulation, scene_from_dict  # noqa: E402

runtime.init("cpu", "f64")
scene = scene_from_dict({
    "sim": {"integrator": "semi_implicit_euler", "dt": 1e-3, "gravity": [0.0, -9.8, 0.0]},
    "body": [{"n": 6, "size": 2.0, "particle_mass": 1.0, "center": [0.0, 2.0, 0.0],
              "stretch": {"k": 2000.0, "damping": 20.0}}],
    "terrain": {"kind": "plane", "point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0]},
    "contact": {"restitution": 0.5, "friction": 0.3},
})
sim = Simulation(scene)
result = sim.run(duration=1.5, fps=30, record=True)
for t, x, v in result.frames[::5]:
    print(f"t = {t:4.2f} s   lowest point y = {x[:, 1].min():+.3f} m   centre y = {x[:, 1].mean():+.3f} m")
if result.diverged:
    sys.exit(f"diverged at t = {result.diverged_at:.3f} s: try a smaller dt")
print(f"{result.steps} steps in {result.wall_seconds:.2f} s")
