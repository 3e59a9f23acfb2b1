"""Contact model with the scene defaults (restitution 0.8, bounce threshold 1 m/s, impact friction):
friction holds on slopes, resting cubes stop, fast drops still bounce, for explicit and implicit methods."""
import numpy as np
import pytest

from taichi_soft.sim.integrators import make_integrator
from taichi_soft.sim.contact.terrain import CONTACT_DEFAULTS

from physics_helpers import build

G = 9.8
# (integrator, dt [s]): two explicit methods at the assignment's step, one implicit at 10x it.
METHODS = [("semi_implicit_euler", 1e-3), ("rk4", 1e-3), ("implicit_euler", 1e-2)]


def _slide(mu, name, dt, degrees=30.0, seconds=1.6, gap=0.02):
    """The cube placed face-down ``gap`` above a slope with the default contact model.

    Returns (times [s], down-slope distance [m] and velocity [m/s] of the centre of mass).
    """
    th = np.radians(degrees)
    n_hat = np.array([np.sin(th), np.cos(th), 0.0])
    size = 1.5
    model, terrain = build(n=4, size=size, gravity=(0.0, -G, 0.0), terrain="tilted_plane",
                           geometry={"point": [0.0, 0.0, 0.0], "normal": list(n_hat)}, contact={"friction": mu},
                           center=tuple(n_hat * (size / 2 + gap)), rotation_axis=(0.0, 0.0, 1.0),
                           rotation_degrees=-degrees)
    assert terrain.restitution[None] == CONTACT_DEFAULTS["restitution"] == 0.8
    down = np.array([np.cos(th), -np.sin(th), 0.0])
    integ = make_integrator(name, model, terrain)
    state = model.state()
    terrain.reset(state.x)
    t, s, u = [], [], []
    chunk = int(round(0.1 / dt))
    for k in range(int(round(seconds / 0.1))):
        assert integ.advance(state, dt, chunk) == chunk
        x, v = state.numpy()
        t.append((k + 1) * chunk * dt)
        s.append(x.mean(axis=0) @ down)
        u.append(v.mean(axis=0) @ down)
    return np.array(t), np.array(s) - (model.x0_np.mean(axis=0) @ down), np.array(u)


@pytest.mark.parametrize("name,dt", METHODS)
def test_friction_holds_below_the_friction_angle(name, dt):
    """mu = 0.7 > tan 30 = 0.577: the cube lands and stays (it slid 7.7 m in 3 s before)."""
    t, s, u = _slide(0.7, name, dt)
    assert abs(s[-1]) < 0.05
    assert abs(u[-1]) < 1e-2


@pytest.mark.parametrize("mu", [0.0, 0.3])
@pytest.mark.parametrize("name,dt", METHODS)
def test_sliding_acceleration_is_coulomb(name, dt, mu):
    """Above the friction angle the cube slides at g (sin 30 - mu cos 30) within 10 %."""
    t, s, u = _slide(mu, name, dt)
    late = t > 0.6  # after the landing
    accel = np.polyfit(t[late], u[late], 1)[0]
    th = np.radians(30.0)
    assert accel == pytest.approx(G * (np.sin(th) - mu * np.cos(th)), rel=0.1)


@pytest.mark.parametrize("name,dt", METHODS)
def test_resting_cube_stops_jittering(name, dt):
    """Dropped 1 m with restitution 0.8, then left to settle: every particle below 1 mm/s."""
    model, terrain = build(n=4, size=1.5, gravity=(0.0, -G, 0.0), terrain="plane",
                           geometry={"point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0]}, center=(0.0, 1.75, 0.0))
    integ = make_integrator(name, model, terrain)
    state = model.state()
    terrain.reset(state.x)
    integ.advance(state, dt, int(round(4.0 / dt)))
    x, v = state.numpy()
    assert np.linalg.norm(v, axis=1).max() < 1e-3
    assert x[:, 1].min() > -0.02


@pytest.mark.parametrize("height,bounces", [(1.0, True), (0.02, False)])
def test_fast_drops_bounce_slow_ones_do_not(height, bounces):
    """Loosely coupled particles with the full default contact model: an impact at 4.4 m/s (above
    the 1 m/s threshold) rebounds at 0.8 times its speed; one at 0.63 m/s does not rebound."""
    model, terrain = build(n=2, size=0.2, gravity=(0.0, -G, 0.0), terrain="plane",
                           geometry={"point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0]},
                           center=(0.0, 0.1 + height, 0.0), stretch=(1e-3, 0.0), shear=(1e-3, 0.0), bend=(1e-3, 0.0))
    integ = make_integrator("rk4", model, terrain)
    state = model.state()
    terrain.reset(state.x)
    bottom = model.x0_np[:, 1] < 0.05 + height
    vy = []
    for _ in range(int(round((np.sqrt(2 * height / G) + 0.05) / 5e-4))):
        integ.advance(state, 5e-4, 1)
        vy.append(state.v.to_numpy()[bottom, 1].mean())
    vy = np.array(vy)
    impact = np.sqrt(2 * G * height)
    if bounces:
        k = np.argmax(vy > 0)
        assert -vy[k - 1] == pytest.approx(impact, rel=0.01)
        assert vy[k] == pytest.approx(0.8 * impact, rel=0.01)
    else:
        assert vy.max() < 1e-6
        assert vy[-1] == pytest.approx(0.0, abs=1e-6)


def test_seed_model_is_one_setting_away():
    """bounce_threshold 0 and impact_friction off give the seed's v' = -kr v_N + v_T exactly."""
    model, terrain = build(n=2, size=0.2, gravity=(0.0, 0.0, 0.0), terrain="plane",
                           geometry={"point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0]},
                           contact={"bounce_threshold": 0.0, "impact_friction": False}, center=(0.0, 0.1, 0.0),
                           stretch=(1e-6, 0.0), shear=(1e-6, 0.0), bend=(1e-6, 0.0), velocity=(0.5, -0.2, 0.0))
    integ = make_integrator("semi_implicit_euler", model, terrain)
    state = model.state()
    terrain.reset(state.x)
    integ.advance(state, 1e-3, 1)
    _, v = state.numpy()
    bottom = model.x0_np[:, 1] < 0.05
    assert v[bottom, 1] == pytest.approx(0.8 * 0.2, rel=1e-6)
    assert v[bottom, 0] == pytest.approx(0.5, rel=1e-6)
    # The default model: that slow approach does not bounce and friction takes mu |dv_N|.
    terrain.set_contact(bounce_threshold=1.0, impact_friction=True)
    state = model.state()
    integ.reset()
    integ.advance(state, 1e-3, 1)
    _, v = state.numpy()
    assert v[bottom, 1] == pytest.approx(0.0, abs=1e-9)
    assert v[bottom, 0] == pytest.approx(0.5 - 0.3 * 0.2, rel=1e-6)
