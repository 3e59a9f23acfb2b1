"""Animation caches (render/caches.py): USD read back with pxr, Point Cache 2 read back with numpy."""
import numpy as np
import pytest
import trimesh

from taichi_soft.render.caches import read_pc2

# The module fixture keeps the recorder's surface (Taichi fields): one runtime for the module (conftest.py).
pytestmark = pytest.mark.taichi_shared


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A torus (mesh body) falling beside a cube onto the plane for 0.3 s at 20 frames/s, written
    to out.usda and pc2/ by the recorder (no Vulkan needed); returns (paths, frames, surface)."""
    from taichi_soft.render.recorder import FrameRecorder, RenderOptions
    from taichi_soft.sim.scene import scene_from_dict
    from taichi_soft.sim.simulation import Simulation

    d = tmp_path_factory.mktemp("caches")
    trimesh.creation.torus(1.0, 0.4, major_sections=24, minor_sections=12).export(d / "torus.obj")
    scene = scene_from_dict({
        "sim": {"dt": 2e-3, "duration": 0.3},
        "body": [{"shape": "mesh", "mesh": str(d / "torus.obj"), "n": 10, "size": 2.0, "center": [0.0, 1.0, 0.0]},
                 {"n": 3, "size": 1.0, "center": [3.0, 1.0, 0.0]}],
        "terrain": {"kind": "plane", "point": [0, 0, 0], "normal": [0, 1, 0]}, "render": {"fps": 20}})
    sim = Simulation(scene)
    options = RenderOptions(usd=d / "out.usda", pc2_dir=d / "pc2", fps=20.0)
    recorder = FrameRecorder(sim, options)
    result = sim.run(0.3, 20.0, on_frame=recorder, record=True)
    recorder.finish()
    return d, result.frames, recorder.surface


def test_usd_has_one_sample_per_frame_matching_the_states(run):
    from pxr import Usd, UsdGeom

    d, frames, surface = run
    stage = Usd.Stage.Open(str(d / "out.usda"))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == 20.0 and stage.GetFramesPerSecond() == 20.0
    assert stage.GetPrimAtPath("/World/terrain_0").IsValid()
    assert not UsdGeom.Mesh(stage.GetPrimAtPath("/World/terrain_0")).GetPointsAttr().GetNumTimeSamples()
    for b, (first, count, first_index, index_count) in enumerate(surface.bodies):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(f"/World/body_{b}"))
        points = mesh.GetPointsAttr()
        assert points.GetTimeSamples() == [float(k) for k in range(len(frames))]
        tris = np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
        np.testing.assert_array_equal(tris + first, surface.triangles_np[first_index // 3:(first_index + index_count) // 3])
        for k, (_, x, _) in enumerate(frames):
            expected = surface.positions(x)[first:first + count]
            np.testing.assert_allclose(np.array(points.Get(float(k))), expected, rtol=0, atol=2e-6 * (1 + np.abs(expected).max()))


def test_pc2_matches_the_states_and_the_rest_obj(run):
    d, frames, surface = run
    for b, (first, count, first_index, index_count) in enumerate(surface.bodies):
        cache = read_pc2(d / "pc2" / f"body_{b}.pc2")
        assert cache.shape == (len(frames), count, 3)
        for k, (_, x, _) in enumerate(frames):
            expected = surface.positions(x)[first:first + count]
            np.testing.assert_allclose(cache[k], expected, rtol=0, atol=2e-6 * (1 + np.abs(expected).max()))
        rest = trimesh.load(d / "pc2" / f"body_{b}.obj", process=False, force="mesh")
        np.testing.assert_allclose(rest.vertices, cache[0], atol=1e-5)
    assert not [p for p in (d / "pc2").iterdir() if p.name.startswith(".")]  # no temporary files left


def test_bad_export_usd_path_exits_2_before_work(cli, tmp_path):
    r = cli("run", "--export-usd", "/proc/out.usd", "--duration", "0.01")
    assert r.returncode == 2 and "--export-usd" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = cli("run", "--set", f"body.0.mesh={tmp_path / 'none.obj'}", "--duration", "0.01")
    assert r.returncode == 2 and "no such file" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
