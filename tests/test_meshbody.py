"""Bodies from closed triangle meshes (meshbody.py): filling, springs, bad input, simulation."""
import numpy as np
import pytest
import trimesh

from taichi_soft.sim.bodies import BodySpec
from taichi_soft.sim.builder import ModelBuilder
from taichi_soft.errors import UserError
from taichi_soft.sim.meshbody import mesh_lattice

R_MAJOR, R_MINOR = 1.0, 0.4  # the test torus, mesh units; its axis is z


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    trimesh.creation.torus(R_MAJOR, R_MINOR, major_sections=48, minor_sections=24).export(d / "torus.obj")
    trimesh.creation.icosphere(subdivisions=3).export(d / "sphere.stl")
    trimesh.creation.box((2.0, 2.0, 2.0)).export(d / "cube.ply")
    open_box = trimesh.creation.box((2.0, 2.0, 2.0))
    open_box.update_faces(np.arange(2, len(open_box.faces)))  # one quad face missing: a fillable hole
    open_box.export(d / "open_box.obj")
    tube = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=32)
    tube.update_faces(np.abs(tube.face_normals[:, 2]) < 0.5)  # no caps: two 32-edge holes
    tube.export(d / "tube.obj")
    trimesh.creation.box((2.0, 2.0, 0.05)).export(d / "sheet.obj")
    (d / "garbage.obj").write_text("this is not a mesh\n")
    (d / "noise.stl").write_bytes(np.random.default_rng(1).integers(0, 256, 2000, dtype=np.uint8).tobytes())
    (d / "short.stl").write_bytes(b"\x01\x02")
    nan_tet = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 nan\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    (d / "nan.obj").write_text(nan_tet)
    (d / "inf.obj").write_text(nan_tet.replace("nan", "inf"))
    # A closed box in a Latin-1 text file (a degree sign in a comment): not UTF-8, still a mesh.
    box = trimesh.creation.box((2.0, 2.0, 2.0))
    (d / "latin1.obj").write_bytes("# 20\u00b0C scan\n".encode("latin-1") + trimesh.exchange.obj.export_obj(box).encode())
    (d / "shape.xyz").write_text("0 0 0\n")
    return d


@pytest.mark.parametrize("name", ["torus.obj", "sphere.stl"])
def test_filled_volume_is_the_mesh_volume(meshes, name):
    """n = 12: each particle stands for an h^3 cell; their total is within 10 % of the mesh's volume."""
    m = mesh_lattice(meshes / name, 12, size=4.0)
    assert m.n_particles * m.h**3 == pytest.approx(m.mesh_volume, rel=0.10)
    assert max(m.grid.shape) == 12 and m.h == pytest.approx(4.0 / 11)


def test_torus_keeps_its_hole(meshes):
    """No particle within the hole's radius; the ring is closed (particles in every 30 degree sector)."""
    m = mesh_lattice(meshes / "torus.obj", 12, size=4.0)
    factor = 4.0 / (2 * (R_MAJOR + R_MINOR))
    rho = np.hypot(m.points[:, 0], m.points[:, 1])
    assert rho.min() > (R_MAJOR - R_MINOR) * factor
    sector = np.floor(np.degrees(np.arctan2(m.points[:, 1], m.points[:, 0])) % 360 / 30).astype(int)
    assert set(sector) == set(range(12))


def test_cube_mesh_is_the_cube(meshes):
    """A cube given as a mesh makes exactly the particles and springs of shape = "cube"."""
    pose = dict(center=(0.5, 3.0, -1.0), rotation_axis=(1.0, 2.0, 0.5), rotation_degrees=25.0, velocity=(1.0, 0.0, 0.0))
    models = []
    for extra in ({}, {"shape": "mesh", "mesh": str(meshes / "cube.ply")}):
        b = ModelBuilder()
        b.add_cube(BodySpec(n=5, size=2.0, **pose, **extra))
        models.append(b.finalize())
    cube, mesh = models
    assert mesh.n_particles == cube.n_particles == 125
    np.testing.assert_allclose(mesh.x0_np, cube.x0_np, atol=1e-12)
    np.testing.assert_allclose(mesh.v0_np, cube.v0_np, atol=1e-12)
    np.testing.assert_array_equal(mesh.pairs_np, cube.pairs_np)
    np.testing.assert_allclose(mesh.rest_np, cube.rest_np, rtol=1e-12)
    np.testing.assert_array_equal(mesh.group_np, cube.group_np)
    assert mesh.spring_counts() == cube.spring_counts()


def test_embedding_reproduces_the_rest_surface(meshes):
    m = mesh_lattice(meshes / "torus.obj", 10, size=3.0)
    rebuilt = (m.embed_weight[..., None] * m.points[m.embed_index]).sum(axis=1)
    np.testing.assert_allclose(rebuilt, m.vertices, atol=1e-9)
    np.testing.assert_allclose(m.embed_weight.sum(axis=1), 1.0, atol=1e-9)


@pytest.mark.parametrize("name, n, word", [
    ("missing.obj", 8, "no such file"),
    ("shape.xyz", 8, "unknown mesh format"),
    ("garbage.obj", 8, "no triangles"),
    ("noise.stl", 8, "not a valid STL file"),
    ("short.stl", 8, "not a valid STL file"),
    ("nan.obj", 8, "1 of the mesh's 4 vertices have non-finite coordinates"),
    ("inf.obj", 8, "non-finite coordinates"),
    ("tube.obj", 8, "not closed"),
    ("sheet.obj", 6, "too thin"),
    ("torus.obj", 3, "too thin"),
])
def test_bad_meshes_are_refused(meshes, name, n, word):
    with pytest.raises(UserError, match=word) as e:
        mesh_lattice(meshes / name, n, size=2.0, key="body.0.mesh")
    assert str(e.value).startswith("body.0.mesh = ") and "\n" not in str(e.value)


def test_a_mesh_in_a_text_file_that_is_not_utf8_is_read(meshes):
    m = mesh_lattice(meshes / "latin1.obj", 5, size=2.0)
    assert m.n_particles == 5 ** 3


def test_open_mesh_is_repaired_and_says_so(meshes):
    m = mesh_lattice(meshes / "open_box.obj", 5, size=2.0)
    assert m.n_particles == 125 and any("not closed" in note for note in m.notes)


def _scene(path, **body):
    """A mesh body of 1.5 m dropped 1 m onto the plane y = 0, firm and well damped."""
    from taichi_soft.sim.scene import scene_from_dict

    spring = {"k": 4000.0, "damping": 90.0}
    b = {"shape": "mesh", "mesh": str(path), "n": 7, "size": 1.5, "center": [0.0, 1.75, 0.0],
         "stretch": spring, "shear": spring, "bend": spring, **body}
    return scene_from_dict({"body": [b], "terrain": {"kind": "plane", "point": [0, 0, 0], "normal": [0, 1, 0]},
                            "sim": {"dt": 1e-3, "duration": 6.0}, "contact": {"restitution": 0.0}})


@pytest.mark.parametrize("body, word", [
    ({"shape": "ball"}, "body.0.shape"),
    ({"scale": 2.0}, "both given"),
    ({"mesh": 3}, "body.0.mesh"),
])
def test_scene_keys_are_checked(meshes, body, word):
    with pytest.raises(UserError, match=word):
        _scene(meshes / "sphere.stl", **body)


def test_scale_sets_the_size(meshes):
    from taichi_soft.sim.scene import scene_from_dict

    b = {"shape": "mesh", "mesh": str(meshes / "sphere.stl"), "n": 6, "scale": 0.5}
    s = scene_from_dict({"body": [b]})
    assert s.data["body"][0]["size"] == pytest.approx(1.0, rel=1e-6)  # the icosphere is 2 units across


def test_mesh_cli_path_is_relative_to_the_current_directory(meshes, monkeypatch):
    from taichi_soft.sim.scene import load_scene

    monkeypatch.chdir(meshes)
    s = load_scene("plane", ["body.0.mesh=sphere.stl", "body.0.n=6"])  # a mesh file alone makes a mesh body
    assert s.data["body"][0]["mesh"] == str(meshes / "sphere.stl") and s.data["body"][0]["shape"] == "mesh"
    with pytest.raises(UserError, match="only for shape"):
        load_scene("plane", ["body.0.shape=cube", "body.0.mesh=sphere.stl"])


def test_mesh_body_comes_to_rest_on_the_plane(meshes):
    """Dropped 1 m: every particle below 1 mm/s after 6 s, none inside the plane; each embedded
    surface vertex stays within half a spacing of where it sat among its particles at rest (its
    distance to the nearest particle it follows grows by less than h / 2)."""
    from taichi_soft.sim.simulation import Simulation

    sim = Simulation(_scene(meshes / "sphere.stl"))
    sim.advance(6000)
    x, v = sim.state.numpy()
    assert np.linalg.norm(v, axis=1).max() < 1e-3
    assert x[:, 1].min() > -0.02
    body = sim.model.bodies[0]
    m = body.mesh
    x0 = sim.model.x0_np[body.particles]
    xf = x[body.particles]
    rest = (m.embed_weight[..., None] * x0[m.embed_index]).sum(axis=1)
    final = (m.embed_weight[..., None] * xf[m.embed_index]).sum(axis=1)
    used = m.embed_weight != 0  # rows are padded with zero weights

    def nearest(verts, pts):
        d = np.linalg.norm(verts[:, None] - pts[m.embed_index], axis=2)
        return np.where(used, d, np.inf).min(axis=1)

    assert np.all(nearest(final, xf) <= nearest(rest, x0) + 0.5 * m.h)
    # the particle stand-in of the surface (demo picking) covers the body's outer particles
    surf = body.surface - body.particles.start
    assert len(surf) and surf.min() >= 0 and surf.max() < m.n_particles
    assert x0[np.unique(surf), 1].max() == x0[:, 1].max() and x0[np.unique(surf), 1].min() == x0[:, 1].min()


def test_mesh_body_on_a_cube(meshes):
    """A torus dropped onto a cube: body-body contact keeps their particles apart; the memory
    model counts the filled lattice."""
    from taichi_soft.sim.memory import estimate
    from taichi_soft.sim.scene import scene_from_dict
    from taichi_soft.sim.simulation import Simulation

    scene = scene_from_dict({
        "sim": {"dt": 1e-3, "duration": 1.0},
        "body": [{"n": 4, "size": 1.0, "center": [0.0, 0.5, 0.0]},
                 {"shape": "mesh", "mesh": str(meshes / "torus.obj"), "n": 9, "size": 2.0, "center": [0.0, 1.6, 0.0],
                  "rotation": {"axis": [1.0, 0.0, 0.0], "degrees": 90.0}}],
        "terrain": {"kind": "plane", "point": [0, 0, 0], "normal": [0, 1, 0]}})
    sim = Simulation(scene)
    assert estimate(scene.data, None, "f64", "cpu")["particles"] == sim.model.n_particles
    sim.advance(600)
    assert not sim.diverged
    x, _ = sim.state.numpy()
    cube, torus = (x[b.particles] for b in sim.model.bodies)
    gap = np.linalg.norm(cube[:, None] - torus[None], axis=2).min()
    radii = 0.5 * (1.0 / 3) + 0.5 * (2.0 / 8)
    assert gap > 0.5 * radii  # touching, not interpenetrating
    assert torus[:, 1].min() > cube[:, 1].max() - radii  # resting on it, not fallen through
