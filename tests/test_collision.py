"""Body-body contact: stacking, a head-on collision, start states that overlap, and scenes with
one body that compile no contact code."""
import numpy as np
import pytest

from taichi_soft.sim.contact.bodies import contact_radii

G = 9.8


def _two_cubes(make_sim, integrator, second_center, gravity=(0.0, -G, 0.0), terrain=None, v=((0, 0, 0), (0, 0, 0))):
    raw_sets = [f"sim.gravity={list(gravity)}"]
    sim_sets = []
    bodies = [[0.0, 0.5, 0.0], list(second_center)]
    for b, c in enumerate(bodies):
        sim_sets += [f"body.{b}.n=4", f"body.{b}.size=1.0", f"body.{b}.center={c}", f"body.{b}.velocity={list(v[b])}"]
    return raw_sets + sim_sets


@pytest.fixture
def stack_scene(tmp_path):
    """A scene file with two small cubes on the plane y = 0 (the second index given by --set)."""
    path = tmp_path / "two.toml"
    path.write_text("[[body]]\n[[body]]\ncenter = [0, 5, 0]\n[terrain]\nkind = \"plane\"\npoint = [0, 0, 0]\n")
    return path


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "velocity_verlet", "rk4"])
def test_cube_dropped_on_a_cube_stays_on_top(make_sim, stack_scene, integrator):
    sets = _two_cubes(make_sim, integrator, [0.1, 2.5, 0.05])
    sim = make_sim(str(stack_scene), sets, integrator=integrator)
    assert sim.contacts is not None
    sim.advance(int(round(4.0 / sim.dt)))
    assert not sim.diverged
    x, v = sim.state.numpy()
    low, high = (x[b.particles] for b in sim.model.bodies)
    spacing = 1.0 / 3
    # The top cube rests on the bottom one's flat top face, one contact distance (a spacing) above
    # it, not inside it.
    assert high[:, 1].min() > low[:, 1].max() + 0.1 * spacing
    assert high.mean(axis=0)[1] == pytest.approx(low.mean(axis=0)[1] + 1.0 + spacing, abs=0.5 * spacing)
    # At rest: the stack's centre of mass still, no particle faster than 5 cm/s.
    assert np.linalg.norm(sim.model.mass_np @ v) / sim.model.mass_np.sum() < 5e-3
    assert np.linalg.norm(v, axis=1).max() < 0.05
    stats = sim.summary(sim.run(0.001, fps=1000))["integrator_stats"]
    assert stats["body_contact_pairs"] > 0 and stats["body_contact_overflows"] == 0


@pytest.mark.parametrize("mu", [0.0, 0.3])
def test_a_cube_slides_on_a_cube_at_mu_g(mu):
    """A 1 m cube (n = 4) settled on a 3 m cube (n = 10, the same 1/3 m spacing) on the plane, then
    pushed to 1.5 m/s along x (``bench contact``'s slide): the relative velocity of the centres of
    mass falls at mu g within 10 % (within 0.1 m/s^2 at mu = 0): the faces are flat (spheres held it
    at 7.3 m/s^2 at mu = 0). The plane's friction, the same mu, holds the lower cube, which carries
    both weights."""
    from taichi_soft.bench.contact import slide

    r = slide("semi_implicit_euler", mu, 1 / 960)
    assert r["settled_speed"] < 0.05 and not r["diverged"]  # at rest on the lower cube before the push
    assert r["deceleration"] == pytest.approx(mu * G, rel=0.1, abs=0.1)
    if mu == 0:
        assert min(r["relative_vx"]) > 1.45  # keeps sliding


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "velocity_verlet"])
def test_head_on_collision_conserves_momentum_and_the_cubes_separate(make_sim, stack_scene, integrator):
    """Free space, no gravity: two cubes at +-2 m/s meet off-centre, exchange momentum, part."""
    sets = _two_cubes(make_sim, integrator, [3.0, 0.7, 0.2], gravity=(0, 0, 0),
                      v=((2.0, 0.0, 0.0), (-2.0, 0.0, 0.0))) + ["terrain.kind=none"]
    sim = make_sim(str(stack_scene), sets, integrator=integrator)
    m = sim.model.mass_np
    a, b = (body.particles for body in sim.model.bodies)

    def momentum_and_gap():
        x, v = sim.state.numpy()
        return (m[:, None] * v).sum(axis=0), v[a].mean(axis=0)[0] - v[b].mean(axis=0)[0], x[b][:, 0].min() - x[a][:, 0].max()

    p0, closing0, _ = momentum_and_gap()
    assert closing0 == pytest.approx(4.0)
    sim.advance(int(round(1.5 / sim.dt)))
    p1, closing1, gap = momentum_and_gap()
    assert not sim.diverged
    np.testing.assert_allclose(p1, p0, atol=1e-9 * m.sum() * 2.0)
    assert closing1 < 0  # moving apart
    assert gap > 0  # and apart: nothing passed through
    assert sim.contacts.stats()["body_contact_pairs"] > 0


def test_one_body_scene_compiles_no_contact_code(make_sim):
    sim = make_sim("plane", ["body.0.n=3"])
    assert sim.contacts is None and sim.integrator.contacts is None
    sim.set_integrator("rk4")
    assert sim.integrator.contacts is None
    assert "body_contact_pairs" not in sim.summary(sim.run(0.002, fps=1000))["integrator_stats"]


def test_contact_radius_is_half_the_spacing(make_sim):
    sim = make_sim("three_cubes")
    r = contact_radii(sim.model)
    for body in sim.model.bodies:
        assert np.all(r[body.particles] == pytest.approx(0.5 * body.spec.size / (body.spec.n - 1)))


@pytest.mark.parametrize("sets,message", [
    (["body.0.center=[0,-5,0]"], "m inside the terrain (plane)"),
    (["--scene", "three_cubes", "body.1.center=[-4,6,0]"], "body.1 starts 1.74 m inside body.0"),
    # Half of a 2 m cube below the bowl's shell: every particle is clear of the shell on its own side.
    (["--scene", "bowl", "terrain.center=[0,7,0]", "body.0.center=[0,0,0]", "body.0.size=2"],
     "body.0 starts cut by the terrain's surface (bowl"),
    # A small ball pokes into the cube's top face between four particles (0.71 m from the nearest).
    (["--scene", "sphere", "terrain.center=[0,1.5,0]", "terrain.radius=0.4", "body.0.n=4", "body.0.size=3",
      "body.0.center=[0,0,0]", "body.0.rotation.degrees=0"], "body.0 starts cut by the terrain's surface (sphere"),
])
def test_start_inside_terrain_or_another_body_is_refused(cli, tmp_path, sets, message):
    args = ["run", "--duration", "0.01", "--summary", tmp_path / "s.json"]
    for s in sets:
        args += [s] if s.startswith("--") or s in ("three_cubes", "bowl", "sphere") else ["--set", s]
    r = cli(*args)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "s.json").exists()


def test_a_terrain_surface_crossing_a_segment_is_found_on_each_kind():
    """Segments through, beside and ending on each surface, against the geometry worked by hand."""
    from taichi_soft.sim.contact.terrain import make_terrain

    a = np.array([[0.0, -2.0, 0.0], [3.0, -2.0, 0.0], [0.0, -9.0, 0.0], [0.0, 1.0, 0.0]])
    b = np.array([[0.0, 2.0, 0.0], [3.0, 2.0, 0.0], [0.0, -5.0, 0.0], [0.0, 0.5, 0.0]])
    plane = make_terrain("plane", 4, {"point": [0.0, 0.0, 0.0], "normal": [0.0, 2.0, 0.0]})
    assert plane.crossed(a, b).tolist() == [True, True, False, False]
    ball = make_terrain("sphere", 4, {"center": [0.0, 0.0, 0.0], "radius": 1.0})
    # through the ball; 3 m beside it; wholly below it; ending inside it (a particle inside: crossed too)
    assert ball.crossed(a, b).tolist() == [True, False, False, True]
    bowl = make_terrain("bowl", 4, {"center": [0.0, 0.0, 0.0], "radius": 7.0})
    # inside the shell; inside; across the bottom of the shell (y = -7); above the rim plane
    assert bowl.crossed(a, b).tolist() == [False, False, True, False]
    assert bowl.crossed(np.array([[6.5, 1.0, 0.0]]), np.array([[7.5, 1.0, 0.0]])).tolist() == [False]  # open top
    assert bowl.crossed(np.array([[6.5, -1.0, 0.0]]), np.array([[7.5, -1.0, 0.0]])).tolist() == [True]
