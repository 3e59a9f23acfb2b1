"""Write an integrator of your own, register it, and run it like a built-in one.

    python examples/custom_integrator.py

``position_verlet`` is Stormer-Verlet in drift-kick-drift form: x_h = x + h/2 v;
v1 = v + h a(x_h, v); x1 = x_h + h/2 v1. Second order and exact for a constant acceleration, so
a cube thrown in vacuum follows the parabola x0 + v0 t + g t^2 / 2 to round-off, where symplectic
Euler (``semi_implicit_euler``) is off by g h t / 2.

What a method declares (``taichi_soft.sim.integrators.base.Integrator``): its ``name``, ``order``,
``force_evals`` and ``description``; its options (``Config``); its own fields (``BUFFERS``, which
the base class allocates and the memory check counts); its linear ``amplification`` matrix (the
divergence hint's stability limit) and ``sweep_dt_cap`` (the accuracy sweep's largest step);
and its step, ``_step_body``, a ``ti.func``. ``register`` refuses a class without those facts.
"""
import pathlib
import sys
from dataclasses import dataclass

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # a checkout needs no pip install

import numpy as np  # noqa: E402
import taichi as ti  # noqa: E402

from taichi_soft import runtime  # noqa: E402
from taichi_soft.sim import BodySpec, Simulation  # noqa: E402
from taichi_soft.sim.footprint import VEC, per_particle  # noqa: E402
from taichi_soft.sim.integrators.base import ExplicitConfig, Integrator, register  # noqa: E402


def position_verlet_amplification(h, jac):
    """One step on a linear mode x'' = -w2 x - g x' (``jac`` = [[0, 1], [-w2, -g]]): the matrix
    taking (x, v) to (x1, v1)."""
    w2, g = -jac[1, 0], -jac[1, 1]
    a = h * h * w2 / 2
    return np.array([[1 - a, h * (1 - a / 2 - h * g / 2)], [-h * w2, 1 - a - h * g]])


@register
@ti.data_oriented
class PositionVerlet(Integrator):
    """x_h = x + h/2 v; v1 = v + h a(x_h, v); x1 = x_h + h/2 v1. Second order, symplectic."""

    name = "position_verlet"
    order = 2
    force_evals = 1
    description = "Stormer-Verlet, drift-kick-drift (an example's integrator)"
    BUFFERS = {"x_half": per_particle("the positions at the half step [m]", VEC)}
    amplification = staticmethod(position_verlet_amplification)
    sweep_dt_cap = 2e-3  # [s]: about its stability limit (h w < 2, as symplectic Euler's) on the sweep's cases

    @dataclass(frozen=True)
    class Config(ExplicitConfig):
        def resolve(self, arch, fast_math, counts):
            # The step reads the forces summed per particle (scatter) and writes the state in place.
            out = self.but(forces="scatter") if self.forces == "auto" else self
            return ExplicitConfig.resolve(out, arch, fast_math, counts)

    @ti.func
    def _step_body(self, x: ti.template(), v: ti.template(), dt, step):
        for i in range(self.n):
            self.x_half[i] = x[i] + 0.5 * dt * v[i]
        self.forces.spring_pass(self.x_half, v)
        for i in range(self.n):
            vn = v[i] + dt * self.forces.accel(self.x_half, v, i, dt)
            self._finish(i, x, v, self.x_half[i] + 0.5 * dt * vn, vn, step)


runtime.init("cpu", "f64")
g, v0, dt, steps = np.array([0.0, -9.8, 0.0]), np.array([1.0, 4.0, 0.0]), 1e-3, 500
for name in ("position_verlet", "semi_implicit_euler"):
    cube = BodySpec(n=3, size=1.0, center=(0.0, 5.0, 0.0), velocity=tuple(v0))
    sim = Simulation.from_parts([cube], terrain="none", integrator=name, dt=dt, gravity=tuple(g))
    x0 = sim.state.x.to_numpy()
    sim.advance(steps)
    t = sim.time
    error = np.abs(sim.state.x.to_numpy() - (x0 + v0 * t + 0.5 * g * t * t)).max()
    print(f"{name:20s} t = {t:.3f} s   distance from the parabola {error:.3e} m   (g h t / 2 = {9.8 * dt * t / 2:.3e} m)")
