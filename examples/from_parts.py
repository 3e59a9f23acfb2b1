"""Build a run in Python from its parts, no scene file: a soft cube falls freely for 0.5 s.

    python examples/from_parts.py
"""
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # a checkout needs no pip install

from taichi_soft import runtime  # noqa: E402
from taichi_soft.sim import BodySpec, Simulation  # noqa: E402

runtime.init("cpu", "f64")
cube = BodySpec(n=3, size=1.0, center=(0.0, 5.0, 0.0))
sim = Simulation.from_parts([cube], terrain="none", integrator="rk4", dt=1e-3, gravity=(0.0, -9.8, 0.0))
y0 = sim.state.x.to_numpy()[:, 1].mean()
sim.advance(500)
drop = y0 - sim.state.x.to_numpy()[:, 1].mean()
print(f"t = {sim.time:.3f} s   centre fell {drop:.9f} m   (g t^2 / 2 = {0.5 * 9.8 * sim.time ** 2:.9f} m)")
