"""Acceptance tests of the implicit integrators, the hard cases: run-time masses, free
flight, no energy growth at large steps on every terrain, restitution's threshold.

Its own module (a fresh Taichi runtime, tests/conftest.py): with test_implicit.py's simulations
in one runtime the field trees ran out (SIGSEGV in Taichi 1.7).
"""
import math

import numpy as np
import pytest

from physics_helpers import build, default_cube_sim, stretched, total_energy
from taichi_soft.sim.integrators import make_integrator

# Module-level caches hold Taichi objects across tests: one runtime for the module (conftest.py).
pytestmark = pytest.mark.taichi_shared

IMPLICIT = ["implicit_euler", "fast_mass_spring"]
FRAME = 1.0 / 60.0
PENETRATION_TOL = 1e-9  # [m] as test_implicit.py: only round-off below the surface
_SIMS = {}


def _sim(terrain, integrator, stiffness=1.0):
    return default_cube_sim(_SIMS, terrain, integrator, FRAME, stiffness)


def _numpy_residual(model, x_n, v_n, x, h):
    """Residual [m/s^2] of the undamped backward-Euler step x_n -> x, from its definition in numpy:
    sqrt(sum_i |grad_i|^2 / m_i / sum_i m_i) / h^2, grad = M (x - y) + h^2 grad E(x)."""
    g = model.gravity[None].to_numpy()
    m = model.mass_np
    grad = m[:, None] * (x - (x_n + h * v_n + h * h * g))
    a, b = model.pairs_np[:, 0], model.pairs_np[:, 1]
    k = model.group_k.to_numpy()[model.group_np]
    d = x[a] - x[b]
    length = np.linalg.norm(d, axis=1)
    f = (h * h * k * (length - model.rest_np) / length)[:, None] * d
    np.add.at(grad, a, f)
    np.add.at(grad, b, -f)
    return math.sqrt(np.sum(grad * grad / m[:, None]) / m.sum()) / (h * h)


@pytest.mark.parametrize("name", IMPLICIT)
def test_mass_change_mid_run_keeps_residual_and_tolerance(name):
    """Model.set_particle_mass between steps (the demo's mass slider): the reported residual is the
    one of the new masses, and the solver stops exactly when it falls below the tolerance."""
    model, terrain = build(n=3, size=1.0, gravity=(0.0, -9.8, 0.0), stretch=(2000.0, 0.0), shear=(1500.0, 0.0),
                           bend=(800.0, 0.0), angular_velocity=(0.0, 3.0, 1.0))
    tol = 0.5  # [m/s^2]
    opts = ({"newton_tol": tol, "velocity_tol": 0.0} if name == "implicit_euler"
            else {"tol": tol, "velocity_tol": 0.0, "iterations": 1000})
    integ = make_integrator(name, model, terrain, opts)
    state = model.state()
    state.set(stretched(model, (1.2, 0.9, 1.0)), model.v0_np)
    h = 0.02
    assert integ.advance(state, h, 3) == 3
    for mass in (4.0, 0.25):
        model.set_particle_mass(mass)
        x_n, v_n = state.numpy()
        assert integ.advance(state, h, 1) == 1
        expected = _numpy_residual(model, x_n, v_n, state.numpy()[0], h)
        history = integ.residual_history()
        assert integ.residual() == pytest.approx(expected, rel=1e-6)
        assert history[-1] == pytest.approx(expected, rel=1e-6)
        assert len(history) >= 2 and history[-1] <= tol < min(history[:-1]), history


@pytest.mark.parametrize("name", IMPLICIT)
def test_free_flight_costs_no_iterations(name):
    """The scene's drop before it lands (1 s at dt = 1/30 s, still 1.8 m above the ground): the
    predictor solves a rigidly falling cube's step exactly, so the solver stops at its first test."""
    sim = _sim("plane", name)
    sim.set_dt(1.0 / 30.0)
    sim.reset()
    sim.integrator.stats()
    sim.advance(30)
    assert sim.measure()["min_terrain_distance"] > 0.5  # not landed yet
    s = sim.integrator.stats()
    key = "newton_iterations_per_step" if name == "implicit_euler" else "local_global_iterations_per_step"
    assert s["steps"] == 30 and s[key] == 0 and s["cg_iterations_per_step"] == 0


# (stiffness scale, dt [s], simulated seconds): the cases where the solvers used to gain energy.
HARD_CASES = [(30.0, 0.1, 3.0), (1000.0, 1.0 / 30.0, 2.5)]


@pytest.mark.parametrize("name", IMPLICIT)
@pytest.mark.parametrize("terrain", ["plane", "tilted_plane", "sphere", "bowl"])
def test_energy_never_rises_at_large_steps(terrain, name):
    """The scene's drop of the default cube with the contact defaults (restitution 0.8 above 1 m/s,
    friction 0.3): total energy never rises above its running minimum (beyond round-off), no
    particle ends a step inside the terrain, and the energy clamp acts on at most 2 % of steps."""
    for stiffness, dt, seconds in HARD_CASES:
        sim = _sim(terrain, name, stiffness)
        sim.set_dt(dt)
        sim.reset()
        sim.integrator.stats()
        steps = int(round(seconds / dt))
        energy = [total_energy(sim.model, *sim.state.numpy())]
        for _ in range(steps):
            sim.advance(1)
            assert not sim.diverged
            assert sim.measure()["min_terrain_distance"] > -PENETRATION_TOL
            energy.append(total_energy(sim.model, *sim.state.numpy()))
        e = np.array(energy)
        rise = e[1:] - np.minimum.accumulate(e)[:-1]
        assert rise.max() <= 1e-9 * np.abs(e).max(), (stiffness, dt, int(rise.argmax()), rise.max())
        s = sim.integrator.stats()
        assert s["steps"] == steps
        assert s["energy_clamped_steps"] <= 0.02 * steps, (stiffness, dt, s)


@pytest.mark.parametrize("name", IMPLICIT)
def test_restitution_follows_the_bounce_threshold(name):
    """The unrotated cube touching the plane and moving down at a speed above the terrain's bounce
    threshold (1 m/s): the bottom layer leaves with restitution (0.8) times its approach speed, as
    Terrain.impact gives the explicit methods; below the threshold it does not bounce."""
    from taichi_soft.sim.lattice import lattice_points

    sim = _sim("plane", name)
    spec = sim.model.bodies[0].spec
    x = lattice_points(spec.n, spec.size) + np.array([0.0, -1.0 + 0.5 * spec.size, 0.0])
    bottom = np.abs(x[:, 1] + 1.0) < 1e-9
    for speed, bounce in ((5.0, 0.8 * 5.0), (0.5, 0.0)):
        v = np.zeros_like(x)
        v[:, 1] = -speed
        sim.reset()
        sim.state.set(x, v)
        sim.advance(1)
        vy = sim.state.numpy()[1][bottom, 1]
        assert vy == pytest.approx(np.full(bottom.sum(), bounce), abs=1e-6), (speed, vy.min(), vy.max())
        assert sim.integrator.stats()["restitution_limited_steps"] == 0
