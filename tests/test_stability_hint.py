"""After a divergence the hint names a step below the method's linear stability limit for
the scene (not just half the step, which diverged again) and the methods that take the step asked
for; the hinted step must really be stable, through a landing on the plane."""
import math

import pytest

from taichi_soft.sim.integrators import linear_stability as ls

# A small cube just above the plane: it lands within the run.
SMALL = ["body.0.n=3", "body.0.center=[0.0, 3.5, 0.0]"]


def _energy(sim):
    f = sim.measure()
    return f["kinetic_energy"] + f["potential_energy"]


@pytest.mark.parametrize("name", ["explicit_euler", "semi_implicit_euler", "velocity_verlet", "midpoint", "rk4"])
def test_the_hinted_step_is_stable(make_sim, name):
    sim = make_sim("plane", [*SMALL, f"sim.integrator={name}", "sim.dt=0.02"])  # one simulation: one compile
    sim.advance(50)
    assert sim.diverged
    hint, text = sim.divergence_hint()
    assert f"try --dt {hint:g}" in text and "implicit_euler" in text and "fast_mass_spring" in text
    assert hint < 0.005  # half of 0.02 s diverges again; the hint is below the limit (~3 ms here)
    sim.reset()
    sim.set_dt(hint)
    start = _energy(sim)
    sim.advance(round(1.2 / hint))  # falls about 0.6 s, lands, bounces
    assert not sim.diverged
    assert _energy(sim) <= start  # the dampers and the impacts only take energy out
    if name == "explicit_euler":  # and the estimate is the limit, not just some small step
        w2, ratios = ls.scene_modes(sim.model)
        over = 1.3 * ls.stable_limit(name, w2, ratios)
        sim.reset()
        sim.set_dt(over)
        sim.advance(round(1.2 / over))
        assert sim.diverged


def test_stability_regions():
    """The textbook limits on one damped oscillator: explicit Euler h < 2/g when overdamped, RK4 on a
    pure oscillator h w < 2 sqrt(2), symplectic Euler h w < 2."""
    assert ls.stable_limit("explicit_euler", 1e4, (1.0, 1.0)) == pytest.approx(2 / 1e4, rel=0.01)
    assert ls.stable_limit("rk4", 1e4, (0.0, 0.0)) * 100 == pytest.approx(2 * math.sqrt(2), rel=0.01)
    assert ls.stable_limit("semi_implicit_euler", 1e4, (0.0, 0.0)) * 100 == pytest.approx(2.0, rel=0.01)
    assert ls.stable_limit("implicit_euler", 1e4, (0.0, 0.0)) == math.inf
    assert ls.stable_limit("explicit_euler", 1e4, (0.0, 0.0)) == 0.0  # undamped: unstable at any step
