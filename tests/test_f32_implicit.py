"""The implicit solvers in f32 at small steps (1 ms), far from the origin.

They iterated on positions and took v = (x_{n+1} - x_n)/h: near 9 m f32 rounds positions to
1e-6 m, as much as a 1 ms step's change of motion (h^2 g = 1e-5 m), and the rounding was biased
(free fall 2.6 % slow); at 300 m the whole step rounded away and the body never fell (exit 0,
nothing said). Now they iterate on the displacement u = x - x_n and sum in f64: free fall is
v = g t, and the centre of mass follows backward Euler's own discrete fall.
"""
import numpy as np
import pytest

from physics_helpers import build
from taichi_soft import runtime
from taichi_soft.sim.integrators import make_integrator


@pytest.fixture(scope="module", autouse=True)
def taichi_runtime():
    """This module runs in f32 (overrides conftest's f64 runtime)."""
    return runtime.init("cpu", "f32")


@pytest.mark.parametrize("name", ["implicit_euler", "fast_mass_spring"])
def test_f32_free_fall_at_1ms_falls_at_g(name):
    """From the scene's 9 m (2.6 % slow before) and from 300 m (frozen before), one integrator
    (its kernels compile once)."""
    dt, steps, g = 1e-3, 100, 9.8
    model, terrain = build(n=3, size=4.0, gravity=(0.0, -g, 0.0), center=(0.0, 9.0, 0.0),
                           stretch=(2000.0, 60.0), shear=(2000.0, 60.0), bend=(2000.0, 60.0))
    integ = make_integrator(name, model, terrain)
    state = model.state()
    for height, fall_tol in ((9.0, 2e-3), (300.0, 2e-2)):  # positions round to 1e-6 m at 9 m, 3e-5 m at 300 m
        x0 = model.x0_np + [0.0, height - 9.0, 0.0]
        state.set(x0, model.v0_np)
        integ.reset()
        assert integ.advance(state, dt, steps) == steps
        x, v = state.numpy()
        # the issue asks for g within 1 %
        assert np.mean(v[:, 1]) == pytest.approx(-g * steps * dt, rel=1e-3), height
        # backward Euler's own discrete fall: x_N - x_0 = -g h^2 N (N + 1) / 2
        fall = np.mean(x[:, 1]) - np.mean(x0[:, 1])
        assert fall == pytest.approx(-g * dt * dt * steps * (steps + 1) / 2, rel=fall_tol), height
        assert integ.stats()["failed_solve_steps"] == 0
