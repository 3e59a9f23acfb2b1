"""Terrain contact: every terrain x every explicit integrator, friction on the slope, the bowl's shell."""
import numpy as np
import pytest

from taichi_soft.sim.integrators import REGISTRY

from physics_helpers import build, simulate

EXPLICIT = [name for name, cls in REGISTRY.items() if not cls.implicit]
TERRAINS = ["plane", "tilted_plane", "sphere", "bowl"]
DEPTH_TOL = 0.02  # m: deepest a particle may sit inside a terrain after a step (2 epsilon)


@pytest.mark.parametrize("terrain", TERRAINS)
@pytest.mark.parametrize("name", EXPLICIT)
def test_default_cube_on_every_terrain(make_sim, terrain, name):
    """3 s at the assignment's dt (velocity Verlet: half of it, its linear stability limit on this
    cube being 0.98 ms): no divergence, nothing inside the terrain, settles on the plane."""
    dt = 0.0005 if name == "velocity_verlet" else 0.001
    sets = ["sim.duration=3.0", f"sim.dt={dt}"]
    if terrain == "plane":
        sets.append("body.0.rotation.degrees=0")  # lands flat: comes to rest within 3 s
    sim = make_sim(terrain, sets, integrator=name)
    assert sim.dt == dt
    deepest = []
    sim.run(3.0, fps=20, on_frame=lambda s: deepest.append(s.measure()["min_terrain_distance"]))
    assert not sim.diverged
    assert min(deepest) > -DEPTH_TOL
    if terrain == "plane":
        final = sim.measure()
        assert final["max_speed"] < 0.5
        # resting on y = -1: the centre of mass of a 4 m cube sits about 2 m above it
        assert final["center_of_mass"][1] == pytest.approx(1.0, abs=0.1)


def _cube_on_slope(friction, name="semi_implicit_euler", seconds=1.0, degrees=45.0):
    """A cube placed face-down on a plane tilted by ``degrees`` about z, released at rest.

    Returns (x0, x, v, down_slope, normal) after ``seconds``.
    """
    th = np.radians(degrees)
    n_hat = np.array([np.sin(th), np.cos(th), 0.0])
    size = 1.5
    center = n_hat * (size / 2 + 0.005)  # bottom face 5 mm above the plane: inside epsilon
    model, terrain = build(n=4, size=size, gravity=(0.0, -9.8, 0.0), terrain="tilted_plane",
                           geometry={"point": [0.0, 0.0, 0.0], "normal": list(n_hat)},
                           contact={"friction": friction, "restitution": 0.0},
                           center=tuple(center), rotation_axis=(0.0, 0.0, 1.0), rotation_degrees=-degrees)
    dt = 1e-3
    x, v, done = simulate(model, terrain, name, dt, int(round(seconds / dt)))
    assert done == int(round(seconds / dt))
    down_slope = np.array([np.cos(th), -np.sin(th), 0.0])
    return model.x0_np, x, v, down_slope, n_hat


@pytest.mark.parametrize("name", EXPLICIT)
def test_friction_holds_cube_on_45_degree_slope(name):
    """mu = 1.2 > tan 45: nothing slides. A cube on 45 degrees is exactly at its tipping angle
    (its centre of mass is above the lower edge), so it may pivot about that edge, but the
    particles that touch the plane stay where they are."""
    x0, x, _, down, n_hat = _cube_on_slope(1.2, name)
    touching = (x @ n_hat) < 0.01
    assert touching.sum() >= 4
    slide = (x - x0)[touching] @ down
    assert np.abs(slide).max() < 0.005


@pytest.mark.parametrize("name", EXPLICIT)
def test_friction_holds_cube_on_30_degree_slope(name):
    """Below the tipping angle the whole cube stays put (mu = 0.7 > tan 30): its contact
    particles do not slide and it comes to rest; only the soft cube's elastic shear under the
    slope's pull moves its centre a little (frictionless, it would have slid 2.45 m)."""
    x0, x, v, down, n_hat = _cube_on_slope(0.7, name, degrees=30.0)
    touching = (x @ n_hat) < 0.01
    assert touching.sum() >= 12  # (nearly) the whole bottom face of 16
    # while the soft cube settles, edge particles briefly lift off and shift by millimetres
    assert np.abs((x - x0)[touching] @ down).max() < 0.02
    assert abs((x - x0).mean(axis=0) @ down) < 0.05
    assert np.abs(v).max() < 0.05


@pytest.mark.parametrize("name", EXPLICIT)
def test_frictionless_cube_slides_at_g_sin45(name):
    t = 1.0
    x0, x, v, down, _ = _cube_on_slope(0.0, name, t)
    a = 9.8 * np.sin(np.pi / 4)
    assert v.mean(axis=0) @ down == pytest.approx(a * t, rel=0.03)
    assert (x - x0).mean(axis=0) @ down == pytest.approx(0.5 * a * t * t, rel=0.03)


def test_friction_slows_but_never_reverses():
    """mu = 0.3 < tan 30: slides with a = g (sin 30 - mu cos 30), always down the slope."""
    t = 1.0
    x0, x, v, down, _ = _cube_on_slope(0.3, "rk4", t, degrees=30.0)
    a = 9.8 * (np.sin(np.pi / 6) - 0.3 * np.cos(np.pi / 6))
    assert v.mean(axis=0) @ down == pytest.approx(a * t, rel=0.05)
    assert (x - x0).mean(axis=0) @ down == pytest.approx(0.5 * a * t * t, rel=0.05)


def test_bowl_outside_wall_is_solid(make_sim):
    """A cube thrown at the bowl's outer wall from the side bounces off it and slides down the
    outside; no particle ever gets inside the shell (checked geometrically, not by the collider)."""
    sim = make_sim("bowl", ["body.0.n=4", "body.0.size=1.5", "body.0.center=[11.5, 3.0, 1.0]",
                            "body.0.velocity=[-6.0, 2.0, 0.0]", "body.0.rotation.degrees=0"],
                   integrator="semi_implicit_euler")
    c, r = np.array([2.0, 7.0, 1.0]), 7.0
    gaps = []

    def check(s):
        x, _ = s.state.numpy()
        below = x[:, 1] < c[1]
        gaps.append((np.linalg.norm(x[below] - c, axis=1) - r).min())

    sim.run(1.5, fps=100, on_frame=check)
    assert not sim.diverged
    assert min(gaps) < 0.05  # it reached the wall ...
    assert min(gaps) > -DEPTH_TOL  # ... and never went through it


def test_cube_dropped_on_the_rim_does_not_pass_through(make_sim):
    """Dropped across the rim, the cube hangs on it: particles on either side stay on their side."""
    sim = make_sim("bowl", ["body.0.n=5", "body.0.size=2.0", "body.0.center=[9.0, 9.0, 1.0]",
                            "body.0.rotation.degrees=0"], integrator="semi_implicit_euler")
    deepest = []
    sim.run(2.0, fps=50, on_frame=lambda s: deepest.append(s.measure()["min_terrain_distance"]))
    assert not sim.diverged
    assert min(deepest) > -DEPTH_TOL
    x, _ = sim.state.numpy()
    assert x[:, 1].min() > 7.0 - 2.0  # caught by the rim, not fallen through to the ground below


def test_bowl_keeps_cube_inside(make_sim):
    sim = make_sim("bowl", ["body.0.n=5", "body.0.size=2.0"], integrator="semi_implicit_euler")
    c, r = np.array([2.0, 7.0, 1.0]), 7.0
    sim.run(3.0, fps=20)
    x, _ = sim.state.numpy()
    assert not sim.diverged
    assert np.all(np.linalg.norm(x - c, axis=1) < r + DEPTH_TOL)
    assert x[:, 1].min() > c[1] - r - DEPTH_TOL


@pytest.mark.parametrize("kr", [0.3, 0.8])
def test_restitution_sets_rebound_speed(kr):
    """Loosely coupled particles dropped from 1 m rebound at kr times the impact speed."""
    model, terrain = build(n=2, size=0.2, gravity=(0.0, -9.8, 0.0), terrain="plane",
                           geometry={"point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0]},
                           contact={"restitution": kr, "friction": 0.0}, center=(0.0, 1.1, 0.0),
                           stretch=(1e-3, 0.0), shear=(1e-3, 0.0), bend=(1e-3, 0.0))
    from taichi_soft.sim.integrators import make_integrator

    integ = make_integrator("rk4", model, terrain)
    state = model.state()
    terrain.reset(state.x)
    bottom = model.x0_np[:, 1] < 1.05
    vy = []
    for _ in range(1000):  # 0.5 s: impact at 0.45 s
        integ.advance(state, 5e-4, 1)
        vy.append(state.v.to_numpy()[bottom, 1].mean())
    vy = np.array(vy)
    k = np.argmax(vy > 0)  # first step after the bounce
    impact = np.sqrt(2 * 9.8 * 1.0)
    assert -vy[k - 1] == pytest.approx(impact, rel=0.01)
    assert vy[k] == pytest.approx(kr * impact, rel=0.01)
