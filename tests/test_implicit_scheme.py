"""The implicit solvers' second-order schemes: ``solver.scheme = "bdf2"`` and ``"sdirk2"`` against
``"backward_euler"`` (the default), where BDF2 falls back to backward Euler, and SDIRK2 under step
refinement through an impact.

Small cubes: the order and the fallback rules do not depend on size.
"""
import math

import numpy as np
import pytest

from physics_helpers import build, moving_cube, simulate, total_energy
from taichi_soft.sim.integrators import make_integrator

IMPLICIT = ["implicit_euler", "fast_mass_spring"]
TIGHT = {
    "implicit_euler": {"newton_iters": 30, "newton_tol": 1e-10, "cg_iters": 2000, "cg_tol": 1e-10, "forcing": "fixed",
                       "velocity_tol": 0.0},
    "fast_mass_spring": {"iterations": 1000, "tol": 1e-8, "velocity_tol": 0.0},
}


@pytest.mark.parametrize("name", IMPLICIT)
def test_bdf2_and_sdirk2_are_second_order_and_backward_euler_first(name):
    """Errors at t = 0.2 s against a tiny-step RK4 reference, converged solves, steps 1/100 to
    1/800 s: BDF2's and SDIRK2's fitted orders are at least 1.8 (BDF2's first step, backward Euler,
    costs no order: its local error is O(h^2)), backward Euler's about 1; both second-order schemes
    are the more accurate at every step. Every BDF2 step after the first is BDF2; no SDIRK2 step
    falls back."""
    model, terrain, x0 = moving_cube(n=3)
    t_end = 0.2
    x_ref, _, _ = simulate(model, terrain, "rk4", 1e-4, 2000, x0=x0)
    steps_list = (20, 40, 80, 160)
    errors = {}
    for scheme in ("bdf2", "sdirk2", "backward_euler"):
        integ = make_integrator(name, model, terrain, {**TIGHT[name], "scheme": scheme})
        state = model.state()
        errors[scheme] = []
        for steps in steps_list:
            state.set(x0, model.v0_np)
            integ.reset()
            integ.stats()
            assert integ.advance(state, t_end / steps, steps) == steps
            errors[scheme].append(float(np.sqrt(np.mean(np.sum((state.x.to_numpy() - x_ref) ** 2, axis=1)))))
            s = integ.stats()
            assert s["steps"] == steps, s
            assert s["bdf2_steps"] == (steps - 1 if scheme == "bdf2" else 0), s
            assert s["sdirk2_fallback_steps"] == 0, s
    dts = [t_end / s for s in steps_list]
    order = {s: np.polyfit(np.log(dts), np.log(e), 1)[0] for s, e in errors.items()}
    assert order["bdf2"] >= 1.8 and order["sdirk2"] >= 1.8, (order, errors)
    assert 0.8 <= order["backward_euler"] <= 1.2, (order, errors)
    for scheme in ("bdf2", "sdirk2"):
        assert all(b < e for b, e in zip(errors[scheme], errors["backward_euler"])), errors


def test_sdirk2_converges_through_a_stiff_impact():
    """The 4^3 study cube of ``bench precision`` at 100x stiffness dropped flat onto the plane:
    halving the step from 1/240 s to 1/960 s never moves SDIRK2's centre of mass more than 10 cm
    further from a tiny-step RK4 reference, and at 1/960 s it is within 30 cm and rebounds to
    within 15 % of the reference's apex above rest. Backward Euler at 1/960 s damps the rebound
    (the impact's fast modes, omega h > 1) and is further off than SDIRK2."""
    from taichi_soft.bench import precision as P

    scene, sets, t_end = P.case_runs("flat", False)[0]
    ref_sim = P.build(scene, sets, "rk4")
    base = ref_sim.model.group_k.to_numpy().copy()
    P.set_stiffness(ref_sim, 100.0, base)
    ref = P.trajectory(ref_sim, P.divide(P.stable_limit(ref_sim, "rk4") / 8), t_end)
    rest = 1.0  # the cube's centre at rest on the plane [m]
    errors = {}
    for scheme, steps in (("sdirk2", (240, 480, 960)), ("backward_euler", (960,))):
        sim = P.build(scene, sets, "implicit_euler", options={"scheme": scheme})
        P.set_stiffness(sim, 100.0, base)
        for n in steps:
            run = P.trajectory(sim, 1.0 / n, t_end)
            errors[scheme, n] = P.compare(run, ref)["com_error"]
            if (scheme, n) == ("sdirk2", 960):
                rise, ref_rise = P.summary(run)["apex"] - rest, P.summary(ref)["apex"] - rest
                assert abs(rise - ref_rise) <= 0.15 * ref_rise, (rise, ref_rise)
    assert errors["sdirk2", 480] <= errors["sdirk2", 240] + 0.1, errors
    assert errors["sdirk2", 960] <= errors["sdirk2", 480] + 0.1, errors
    assert errors["sdirk2", 960] <= 0.3, errors
    assert errors["backward_euler", 960] > errors["sdirk2", 960] + 0.2, errors


@pytest.mark.parametrize("name", IMPLICIT)
def test_bdf2_steps_only_where_the_history_is_smooth(name):
    """A cube dropped on the plane at 1/60 s: a BDF2 step never touches the terrain (its start, its
    end and the previous step's end are clear of it), the first step and the step after any
    contact are backward Euler, BDF2 resumes in flight after the bounce, and a state set from
    outside (as the demo or a reset does) restarts the history."""
    model, terrain = build(n=3, size=1.0, gravity=(0.0, -9.8, 0.0), terrain="plane",
                           geometry={"point": [0.0, -0.6, 0.0], "normal": [0.0, 1.0, 0.0]},
                           center=(0.0, 1.0, 0.0), velocity=(0.5, -3.0, 0.0))
    eps = terrain.epsilon[None]
    integ = make_integrator(name, model, terrain, {"scheme": "bdf2"})
    state = model.state()
    state.set(model.x0_np, model.v0_np)
    terrain.reset(state.x)
    integ.stats()
    lowest = lambda: state.x.to_numpy()[:, 1].min() + 0.6  # noqa: E731  (distance to the plane [m])
    kinds, clear = [], []
    for _ in range(90):
        before = lowest()
        assert integ.advance(state, 1.0 / 60.0, 1) == 1
        kinds.append(integ.stats()["bdf2_steps"])
        clear.append((before, lowest()))
    assert kinds[0] == 0
    touched = [b < eps or a < eps for b, a in clear]
    assert any(touched), "the cube never landed"
    for k in range(1, len(kinds)):
        if kinds[k]:
            assert clear[k][0] > 0 and clear[k][1] > 0 and clear[k - 1][1] >= eps, (k, clear[k - 1], clear[k])
    first_touch = touched.index(True)
    assert all(kinds[1:first_touch - 1]), kinds[:first_touch]  # free fall: BDF2 after the first step
    assert any(kinds[k] for k in range(first_touch, len(kinds)) if not touched[k]), kinds  # resumes in flight
    # A state set between steps is not the history: the next step is backward Euler.
    x, v = state.numpy()
    state.set(x + np.array([0.0, 2.0, 0.0]), v)
    integ.advance(state, 1.0 / 60.0, 2)
    assert integ.stats()["bdf2_steps"] == 1


@pytest.mark.parametrize("name", IMPLICIT)
def test_bdf2_keeps_the_energy_bound_without_dampers(name):
    """Undamped springs, 60 steps of 1/60 s, converged solves: total energy never rises above its
    running minimum with any scheme (SDIRK2 takes a second stage that gained energy again as
    backward Euler: counted, not clamped). Backward Euler's steps never need the clamp (its energy is
    monotone); BDF2's is not (its monotone quantity is a two-step G-norm), so the end-of-step check
    takes the excess on some steps, and every such step is counted in stats(). BDF2 dissipates
    the oscillation less: it ends with more energy."""
    model, terrain, x0 = moving_cube(n=3, damping=0.0)
    final, clamped = {}, {}
    for scheme in ("bdf2", "sdirk2", "backward_euler"):
        integ = make_integrator(name, model, terrain, {**TIGHT[name], "scheme": scheme})
        state = model.state()
        state.set(x0, model.v0_np)
        energies = [total_energy(model, x0, model.v0_np)]
        for _ in range(60):
            assert integ.advance(state, 1.0 / 60.0, 1) == 1
            energies.append(total_energy(model, *state.numpy()))
        e = np.array(energies)
        assert np.all(e[1:] - np.minimum.accumulate(e)[:-1] <= 1e-9 * np.abs(e).max()), (scheme, e)
        s = integ.stats()
        assert s["steps"] == 60 and (s["bdf2_steps"] > 0) == (scheme == "bdf2")
        if scheme == "sdirk2":  # a second stage that gained energy is taken again, never clamped
            assert s["energy_clamped_steps"] == 0, s
        final[scheme], clamped[scheme] = e[-1], s["energy_clamped_steps"]
    assert clamped["backward_euler"] == 0
    assert final["bdf2"] > final["backward_euler"], (final, clamped)
    assert math.isfinite(final["bdf2"])


@pytest.mark.parametrize("name", IMPLICIT)
def test_sdirk2_slides_as_far_as_coulomb_allows(name):
    """The study cube resting face down on the plane, pushed at 3 m/s, at 1/60 s: with SDIRK2 its
    centre of mass slides v^2 / (2 mu g) within 5 %, as a rigid block under Coulomb friction (a
    held particle's second stage carries friction and gravity along the surface over the whole step)."""
    from taichi_soft.bench import plausibility as Q
    from taichi_soft.bench import precision as P

    scene, sets, t_end = Q.push_run(False)
    sim = P.build(scene, sets, name, options={"scheme": "sdirk2"})
    run = Q._energy_run(sim, 1.0 / 60.0, t_end)
    mu, g = float(sim.terrain.friction[None]), float(np.linalg.norm(sim.model.gravity.to_numpy()))
    expected = Q.PUSH_SPEED**2 / (2.0 * mu * g)
    assert abs(Q.slide_distance(run) - expected) <= 0.05 * expected, (Q.slide_distance(run), expected)
