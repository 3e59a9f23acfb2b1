"""Offscreen rendering, video, compare mosaics and mesh export (docs/rendering.md).

GGUI tests need a Vulkan device (Mesa's lavapipe is enough); it is probed once, in a subprocess
so that a driver crash cannot take pytest down; without one those tests fail with the reason
(conftest.missing_tool).
Frames are tiny and bodies small (n = 4) to keep the file fast on two CPU cores.
"""
import functools
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, missing_tool, run_cli
from taichi_soft.render import overlay
from taichi_soft.render.camera import CameraSpec, project, projection_matrix, scene_camera, view_matrix

# Module fixtures hold Taichi objects across tests: one runtime for the module (conftest.py).
pytestmark = pytest.mark.taichi_shared

SMALL = ["--set", "body.0.n=4", "--resolution", "96x64", "--fps", "20"]
NO_VULKAN = {"VK_ICD_FILENAMES": "/nonexistent"}  # the Vulkan loader then finds no driver at all


@functools.lru_cache(maxsize=1)
def vulkan_probe() -> str | None:
    """None if a hidden GGUI window opens here, else why not (one line)."""
    # Through runtime.init, not a bare ti.init: Taichi's default cache limit (100 MiB) evicts a
    # quarter of ~/.cache/taichi when any process with it exits (runtime.KERNEL_CACHE_BYTES).
    code = (f"import sys; sys.path.insert(0, {str(ROOT)!r}); from taichi_soft import runtime; runtime.init('cpu'); "
            "import taichi as ti; ti.ui.Window('probe', (16, 16), show_window=False)")
    try:
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT / "tests")
    except subprocess.TimeoutExpired:
        return "opening a GGUI window timed out"
    if p.returncode == 0:
        return None
    lines = [line for line in (p.stderr + p.stdout).splitlines() if line.strip()]
    return lines[-1] if lines else f"exit status {p.returncode}"


@pytest.fixture(scope="session")
def vulkan():
    reason = vulkan_probe()
    if reason:
        missing_tool(f"no usable Vulkan device for GGUI offscreen rendering: {reason}")


@pytest.fixture(scope="module")
def renderer(vulkan, tmp_path_factory):
    """One 160 x 96 hidden window for every in-process test (a process gets one Taichi runtime).

    Dear ImGui inside GGUI saves ``imgui.ini`` in the working directory: keep it out of the repo.
    """
    from taichi_soft.render.renderer import Renderer

    old = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("ggui"))
    r = Renderer(160, 96)
    yield r
    r.close()
    os.chdir(old)


def cli(*args, env=None, cwd=None):
    """``python main.py ARGS`` run in ``cwd`` (default: the repo root)."""
    if env is None:
        return run_cli(*args, cwd=cwd or ROOT)
    full = dict(os.environ, **env)
    return subprocess.run([sys.executable, str(ROOT / "main.py"), *map(str, args)], cwd=cwd or ROOT, env=full,
                          capture_output=True, text=True, timeout=600)


def small_scene(name):
    """A shipped scene with every body cut down to 4 x 4 x 4 particles."""
    from taichi_soft.sim.integrators import names
    from taichi_soft.sim.scene import load_scene

    n_bodies = len(load_scene(name).data["body"])
    return load_scene(name, [f"body.{b}.n=4" for b in range(n_bodies)], integrator_names=names())


def banner_red(img):
    """Pixels of the red "diverged" banner (not of an orange cube, whose green is at least 45 % of its red)."""
    img = np.asarray(img, dtype=np.int32)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r > 150) & (g < 70) & (b < 70) & (r - g > 120)


def saturation(pixels):
    pixels = np.asarray(pixels, dtype=np.int32)
    return pixels.max(axis=-1) - pixels.min(axis=-1)


# -- cameras (no Vulkan needed) -------------------------------------------------------------------
def test_camera_matrices_match_ggui():
    import taichi as ti

    spec = CameraSpec((3.0, 4.0, 10.0), (0.0, 1.0, -0.5), (0.0, 1.0, 0.0), 40.0)
    cam = ti.ui.Camera()
    cam.position(*spec.position)
    cam.lookat(*spec.lookat)
    cam.up(*spec.up)
    cam.fov(spec.fov)
    # GGUI hands its matrices back transposed (column-major rows).
    np.testing.assert_allclose(np.array(cam.get_view_matrix()).T, view_matrix(spec), atol=1e-5)
    ggui_proj = np.array(cam.get_projection_matrix(16 / 9)).T
    ours = projection_matrix(spec, 16 / 9)
    # x, y scale and the perspective divide (w = -z) are what pixel positions depend on.
    np.testing.assert_allclose([ggui_proj[0, 0], ggui_proj[1, 1], ggui_proj[3, 2]], [ours[0, 0], ours[1, 1], ours[3, 2]],
                               rtol=1e-5)


@pytest.mark.parametrize("name", ["plane", "tilted_plane", "sphere", "bowl", "three_cubes", "free_float"])
def test_default_camera_keeps_start_and_terrain_in_frame(name):
    from taichi_soft.sim.scene import load_scene

    data = load_scene(name).data
    w, h = 1280, 720
    cam = scene_camera(data, w / h, top_margin=overlay.INFO_MARGIN)
    points = [b["center"] for b in data["body"]]
    if data["terrain"]["kind"] in ("sphere", "bowl"):
        points.append(data["terrain"]["center"])
    px = project(points, cam, w, h)
    assert np.all((px[:, 0] > 0) & (px[:, 0] < w) & (px[:, 1] > overlay.INFO_MARGIN * h) & (px[:, 1] < h)), px
    assert cam.follow == (data["terrain"]["kind"] in ("tilted_plane", "sphere"))


@pytest.mark.parametrize("name", ["plane", "tilted_plane", "sphere", "bowl", "three_cubes", "free_float"])
def test_default_camera_keeps_every_body_in_frame_for_the_whole_run(name):
    """At every output frame of the scene's default duration, each body's centre projects into
    the image as the default camera (following where it follows) sees it: checked by projection,
    without rendering. Bodies are cut to 4^3 particles (the camera, not the physics, is tested;
    a following camera keeps them in view whatever the contact model does)."""
    from taichi_soft.sim.simulation import Simulation

    scene = small_scene(name)
    sim = Simulation(scene, integrator="semi_implicit_euler")
    w, h = scene.data["render"]["resolution"]
    cam = scene_camera(scene.data, w / h, top_margin=overlay.INFO_MARGIN)
    bodies = [b.particles for b in sim.model.bodies]
    outside = []

    def on_frame(s):
        x = s.state.x.to_numpy()
        px = project([x[p].mean(axis=0) for p in bodies], cam.following(x.mean(axis=0)), w, h)
        if not np.all((px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)):
            outside.append(round(s.time, 3))

    result = sim.run(scene.sim["duration"], scene.data["render"]["fps"], on_frame=on_frame)
    assert sim.time == pytest.approx(scene.sim["duration"]), result
    assert outside == [], f"bodies out of frame at t = {outside[:5]}... ({len(outside)} frames)"


def test_scene_camera_follow_key():
    """``render.camera.follow`` turns tracking on or off, also beside other camera keys."""
    from taichi_soft.errors import UserError
    from taichi_soft.sim.scene import load_scene

    assert not scene_camera(load_scene("plane").data, 16 / 9).follow
    assert scene_camera(load_scene("plane", ["render.camera.follow=true"]).data, 16 / 9).follow
    fixed = load_scene("plane", ["render.camera.fov=30", "render.camera.follow=true"]).data
    assert scene_camera(fixed, 16 / 9).follow and scene_camera(fixed, 16 / 9).fov == 30.0
    assert not scene_camera(load_scene("sphere", ["render.camera.follow=false"]).data, 16 / 9).follow
    with pytest.raises(UserError, match="true or false"):
        load_scene("plane", ["render.camera.follow=1"])


def test_scene_camera_keys_override_default():
    from taichi_soft.sim.scene import load_scene

    data = load_scene("plane", ["render.camera.position=[1, 2, 30]", "render.camera.fov=55"]).data
    cam = scene_camera(data, 16 / 9)
    assert cam.position == (1.0, 2.0, 30.0) and cam.fov == 55.0 and not cam.follow
    assert scene_camera(data, 16 / 9, follow=True).following([5, 0, 0]).lookat[0] == pytest.approx(cam.lookat[0] + 5)


# -- frames ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["plane", "tilted_plane", "sphere", "bowl", "three_cubes", "free_float"])
def test_frame_shows_bodies_and_terrain(renderer, name):
    """Every body and the terrain are in the frame, where the camera matrices put them.

    Run as ``compare`` and the demo's terrain switch use GGUI: many views built, drawn and
    dropped in one process and one window (a view per scene, all in one window). Drawn with
    plain ``scene.mesh``, GGUI 1.7.4 dropped a whole mesh from every frame of some views (an
    uninitialised transform buffer, see ``renderer.draw_mesh``): this test then failed in about
    half of its runs, always for the whole of a view (body 1 of three_cubes, the tilted plane's
    cube, a terrain).
    """
    from taichi_soft.render.renderer import SimulationView
    from taichi_soft.sim.simulation import Simulation

    scene = small_scene(name)
    sim = Simulation(scene)
    cam = scene_camera(scene.data, renderer.aspect)
    view = SimulationView(sim)
    first = renderer.render(view, cam)
    check_bodies_and_terrain(first, scene, cam)
    np.testing.assert_array_equal(renderer.render(view, cam), first)  # the same state draws the same frame


def pixel_differences(a, b):
    """Per pixel, the largest difference over R, G, B between two uint8 images, in 8-bit levels."""
    return np.abs(a.astype(int) - b.astype(int)).max(axis=-1)


@pytest.mark.parametrize("name", ["plane", "sphere", "bowl", "three_cubes"])
def test_fast_paths_match_the_per_pixel_reference(renderer, name):
    """Per-vertex lighting (GGUI, and the Taichi rasterizer) against GGUI's own per-pixel lighting,
    the slow path it replaces, on one frame of a falling, deformed body.

    Tolerances: both use the same Lambertian formula, evaluated per vertex or per pixel, so they
    agree exactly at vertices and differ inside a triangle only by how the lighting curves across
    it. On the terrain (1 m tiles, lights tens of metres away) that is below 2 levels; on a body it
    is largest on the rounded edges, where the normal turns through 90 degrees within one lattice
    cell, and a 4^3 body is all edges: measured up to 34 levels, on 2-3 % of the pixels at most.
    The Taichi rasterizer at ``quality="low"`` draws what GGUI can draw, the same vertex colours
    (the checker filtered alike), so it differs from GGUI's per-vertex frame only on pixels whose
    centre lies on an edge between two triangles (Vulkan's top-left rule and our
    nearer-then-smaller-key rule may pick different sides): isolated pixels. Its shadows
    (``medium``, GGUI has none) change only pixels inside the screen box of the bodies and their
    shadow volume, and leave every other pixel as it was; ``high`` (supersampled too) still shows
    the bodies and the terrain where they are.
    """
    from taichi_soft.render.renderer import SimulationView
    from taichi_soft.render.taichi_renderer import TaichiRenderer
    from taichi_soft.sim.simulation import Simulation

    sim = Simulation(small_scene(name))
    sim.advance(300)  # mid-fall, the body deformed by its spin-up
    view = SimulationView(sim)
    cam = scene_camera(sim.scene.data, renderer.aspect)
    view.per_pixel_lighting = True
    reference = renderer.render(view, cam)
    view.per_pixel_lighting = False
    vertex = renderer.render(view, cam)
    taichi = TaichiRenderer(renderer.width, renderer.height, quality="low").render(view, cam)
    d = pixel_differences(vertex, reference)
    assert d.mean() < 1.0 and (d > 8).mean() < 0.05 and d.max() <= 60, (d.mean(), (d > 8).mean(), d.max())
    t = pixel_differences(taichi, vertex)
    assert t.mean() < 0.05 and (t > 8).mean() < 0.002, (t.mean(), (t > 8).mean(), t.max())
    check_bodies_and_terrain(taichi, sim.scene, cam)
    medium = TaichiRenderer(renderer.width, renderer.height, quality="medium")
    shadowed = medium.render(view, cam)
    boxes = np.zeros(shadowed.shape[:2], bool)
    for rect in (medium.shadow.rect, medium.bodies.rect):
        boxes[rect[1]:rect[3], rect[0]:rect[2]] = True
    changed = pixel_differences(shadowed, taichi) > 0
    # (That shadows appear at all, and where, is tests/test_shading.py's.)
    assert not (changed & ~boxes).any(), (changed.sum(), (changed & ~boxes).sum())
    check_bodies_and_terrain(shadowed, sim.scene, cam)
    check_bodies_and_terrain(TaichiRenderer(renderer.width, renderer.height, quality="high").render(view, cam),
                             sim.scene, cam)


def test_terrain_is_drawn_from_the_live_terrain(renderer):
    """A geometry changed at run time (``set_geometry``) is drawn: the renderer reads the
    terrain object the simulation collides with, not the scene file."""
    from taichi_soft.render.renderer import BACKGROUND, SimulationView
    from taichi_soft.sim.simulation import Simulation

    scene = small_scene("sphere")
    sim = Simulation(scene)
    view = SimulationView(sim)
    cam = scene_camera(scene.data, renderer.aspect)
    t = scene.data["terrain"]
    low = np.add(t["center"], [0.0, -0.6 * t["radius"], 0.0])  # inside the ball, below the cube
    col, row = (int(v) for v in project([low], cam, 160, 96)[0])
    background = np.round(np.array(BACKGROUND) * 255).astype(int)
    before = renderer.render(view, cam)[row, col].astype(int)
    assert np.abs(before - background).max() > 10 and saturation(before) < 70, before  # the ball
    sim.terrain.set_geometry(t["center"], 0.3 * t["radius"])
    after = renderer.render(view, cam)[row, col].astype(int)
    assert np.abs(after - background).max() <= 2, after  # the shrunken ball no longer covers it


def check_bodies_and_terrain(img, scene, cam):
    from taichi_soft.render.meshes import BODY_COLORS
    from taichi_soft.render.renderer import BACKGROUND

    assert img.shape == (96, 160, 3) and img.dtype == np.uint8
    background = np.round(np.array(BACKGROUND) * 255).astype(int)
    is_background = np.abs(img.astype(int) - background).max(axis=-1) <= 2
    assert is_background.mean() < 0.95, "the frame is (almost) all background"

    # Each body's centre projects onto a pixel of that body's colour: saturated, same dominant channel.
    for b, body in enumerate(scene.data["body"]):
        col, row = project([body["center"]], cam, 160, 96)[0]
        pixel = img[int(row), int(col)]
        color = BODY_COLORS[b % len(BODY_COLORS)]
        assert saturation(pixel) > 60, (b, pixel)
        assert int(np.argmax(pixel)) == int(np.argmax(color)), (b, pixel, color)

    # The terrain is drawn where the collision shape is: grey-blue, unsaturated, not background.
    t = scene.data["terrain"]
    terrain_like = (~is_background) & (saturation(img) < 70)
    if t["kind"] == "none":
        assert terrain_like.mean() < 0.02
        return
    assert terrain_like.mean() > 0.04  # the smallest, the sphere scene's ball, covers 5 % of the frame
    if t["kind"] == "sphere":
        probe = np.add(t["center"], [0, t["radius"], 0])  # the top, where the cube lands
    elif t["kind"] == "bowl":
        probe = np.add(t["center"], [0, -t["radius"], 0])  # the bottom of the inside
    else:  # plane kinds: the first body's centre dropped onto the plane along the normal
        n = np.asarray(t["normal"]) / np.linalg.norm(t["normal"])
        c = np.asarray(scene.data["body"][0]["center"])
        probe = c - np.dot(c - t["point"], n) * n
    col, row = project([probe], cam, 160, 96)[0]
    assert terrain_like[int(row), int(col)], img[int(row), int(col)]


def test_springs_and_particles_toggle(renderer):
    from taichi_soft.render.renderer import SimulationView
    from taichi_soft.sim.simulation import Simulation

    sim = Simulation(small_scene("free_float"))
    cam = scene_camera(sim.scene.data, renderer.aspect)
    surface = renderer.render(SimulationView(sim), cam)
    springs = renderer.render(SimulationView(sim, surface=False, springs=True), cam)
    particles = renderer.render(SimulationView(sim, surface=False, particles=True), cam)
    orange = (surface[..., 0].astype(int) - surface[..., 2] > 100).sum()
    assert orange > 200
    # Springs: blue (stretch), green (shear) and magenta (bend) lines, no orange surface.
    assert (springs[..., 0].astype(int) - springs[..., 2] > 100).sum() < orange / 10
    assert (springs[..., 1].astype(int) - springs[..., 0] > 60).sum() > 20  # green shear lines
    assert (particles.astype(int).max(axis=-1) < 80).sum() > 20  # dark particle spheres


def test_overlay_shows_time_and_changes_with_it():
    info = overlay.RunInfo("plane", "rk4", 0.001, "2000 N/m", "60 N s/m")
    first, later = info.lines(0.0, 0.0), info.lines(1.25, -27199.5)
    # the change since t = 0, not the total against y = 0 (88 kJ at the default drop's start)
    assert "t =   0.000 s" in first[2] and "E - E(0) = +0.0 J" in first[2] and "rk4" in first[0]
    assert "E - E(0) = -27200 J" in later[2] and overlay.energy_text(-12.34) == "-12.3 J"
    a = np.full((72, 128, 3), 200, np.uint8)
    b = a.copy()
    overlay.draw_info(a, first)
    overlay.draw_info(b, later)
    assert (a != 200).any(), "overlay drew nothing"
    assert (a != b).any(), "a later time draws the same overlay"
    assert overlay.value_range([600, 2000, 8000], "N/m") == "600..8000 N/m"


def test_compare_tile_labels_scale_with_the_tile():
    """Sub-labels of a 640 x 360 mosaic of four tiles were 8-px type (about 6 px of glyph)."""
    subtitle = "dt = 0.002 s | t = 1.500 s | E - E(0) = -42761 J"
    sizes = {(w, h): overlay.title_sizes(h, w, "semi_implicit_euler", subtitle) for w, h in ((320, 180), (640, 360))}
    assert sizes[(320, 180)][1] >= 10 and sizes[(640, 360)][1] > sizes[(320, 180)][1]
    for (w, h), (big, small) in sizes.items():
        assert overlay._text_size(subtitle, overlay.font(small))[0] <= 0.94 * w
        assert overlay._text_size("semi_implicit_euler", overlay.font(big, "bold"))[0] <= 0.94 * w
    img = np.full((180, 320, 3), 200, np.uint8)
    overlay.draw_title(img, "semi_implicit_euler", subtitle)
    rows = np.flatnonzero((img.max(axis=-1) > 230).any(axis=1))  # white text rows
    assert rows.min() > 100 and rows.max() < 180


# -- command line ---------------------------------------------------------------------------------
def test_run_writes_video_and_frames(vulkan, tmp_path):
    import imageio.v3 as iio

    video, frames = tmp_path / "out.mp4", tmp_path / "frames"
    p = cli("run", "--duration", "0.3", *SMALL, "--video", video, "--frames", frames, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert f"video: {video}" in p.stdout
    decoded = iio.imread(video)
    assert decoded.shape == (7, 64, 96, 3)  # t = 0, 0.05, ..., 0.3 s
    pngs = sorted(frames.glob("frame_*.png"))
    assert [f.name for f in pngs] == [f"frame_{k:05d}.png" for k in range(7)]
    first, last = iio.imread(pngs[0]), iio.imread(pngs[-1])
    assert first.shape == (64, 96, 3)
    top_left = (slice(0, 14), slice(0, 90))  # the overlay's panel, with "t = ..." in it
    assert (first[top_left] != last[top_left]).any()
    assert not list(tmp_path.glob(".*")), "temporary files left behind"


def test_gif(vulkan, tmp_path):
    import imageio.v3 as iio

    gif = tmp_path / "out.gif"
    p = cli("run", "--duration", "0.1", *SMALL, "--video", gif, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert iio.imread(gif).shape[0] == 3


def test_diverged_run_closes_video_with_banner(vulkan, tmp_path):
    import imageio.v3 as iio

    video = tmp_path / "div.mp4"
    p = cli("run", "--integrator", "explicit_euler", "--dt", "0.01", "--duration", "1", *SMALL, "--video", video,
            cwd=tmp_path)
    assert p.returncode == 3, p.stderr
    assert "diverged at t =" in p.stderr
    frames = iio.imread(video)
    assert len(frames) >= 20 + 1  # the last good frame held for ~1 s at 20 fps
    assert banner_red(frames[-1]).mean() > 0.05, "no DIVERGED banner on the last frame"
    assert banner_red(frames[0]).mean() < 0.005


def test_compare_mosaic_marks_diverged_tile(vulkan, tmp_path):
    import imageio.v3 as iio

    video = tmp_path / "cmp.mp4"
    p = cli("compare", "--integrators", "explicit_euler,rk4", "--dt", "0.003", "--duration", "0.5",
            "--set", "body.0.n=4", "--fps", "10", "--resolution", "320x180", "--video", video, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "explicit_euler" in p.stdout and "diverged at t =" in p.stdout.splitlines()[0]
    assert "rk4" in p.stdout.splitlines()[1] and "ran to" in p.stdout.splitlines()[1]
    frames = iio.imread(video)
    assert frames.shape == (6, 180, 320, 3)  # two 160 x 180 tiles side by side
    red = banner_red(frames[-1])
    assert red[:, :160].mean() > 0.03, "the diverged tile is not marked"
    assert red[:, 160:].mean() < 0.005, "the healthy tile is marked"


def test_no_vulkan_is_one_line_and_overwrites_nothing(tmp_path):
    video = tmp_path / "keep.mp4"
    video.write_bytes(b"old video")
    p = cli("run", "--duration", "0.1", *SMALL, "--renderer", "ggui", "--video", video, env=NO_VULKAN, cwd=tmp_path)
    assert p.returncode == 2
    assert len(p.stderr.strip().splitlines()) == 1 and "Vulkan" in p.stderr, p.stderr
    assert video.read_bytes() == b"old video"
    assert sorted(f.name for f in tmp_path.iterdir()) == ["keep.mp4"]


def test_video_without_vulkan_through_the_taichi_renderer(tmp_path):
    """``--renderer auto`` (the default) draws with Taichi kernels when Vulkan offers no GPU:
    here no Vulkan driver at all, and the video is still written."""
    import imageio.v3 as iio

    video = tmp_path / "out.mp4"
    p = cli("run", "--duration", "0.1", *SMALL, "--no-overlay", "--video", video, env=NO_VULKAN, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    frames = iio.imread(video)
    assert frames.shape == (3, 64, 96, 3)
    orange = (frames[0, ..., 0].astype(int) - frames[0, ..., 2] > 100).sum()  # the cube
    assert orange > 20, orange
    p = cli("run", "--duration", "0.1", *SMALL, "--renderer", "taichi", "--springs", "--video", video, cwd=tmp_path)
    assert p.returncode == 2 and "--renderer ggui" in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr


def test_mesh_export_needs_no_vulkan(tmp_path):
    meshes = tmp_path / "meshes"
    p = cli("run", "--duration", "0.1", "--set", "body.0.n=4", "--fps", "20", "--export-mesh", meshes,
            env=NO_VULKAN, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    files = sorted(meshes.glob("mesh_*.ply"))
    assert len(files) == 3
    data = files[-1].read_bytes()
    header, body = data.split(b"end_header\n", 1)
    assert b"element vertex 56" in header and b"element face 108" in header  # 4^3 - 2^3 surface particles
    vert = np.frombuffer(body[:56 * 25], dtype=[("p", "<f4", 3), ("n", "<f4", 3), ("body", "u1")])
    faces = np.frombuffer(body[56 * 25:], dtype=[("count", "u1"), ("idx", "<i4", 3)])
    assert np.all(faces["count"] == 3) and faces["idx"].max() == 55
    np.testing.assert_allclose(np.linalg.norm(vert["n"], axis=1), 1.0, atol=1e-5)
    # Outward winding: face normals point away from the body's centre.
    p0, p1, p2 = (vert["p"][faces["idx"][:, k]] for k in range(3))
    outward = np.einsum("ij,ij->i", np.cross(p1 - p0, p2 - p0), (p0 + p1 + p2) / 3 - vert["p"].mean(axis=0))
    assert np.all(outward > 0)


def test_obj_writer(tmp_path):
    from taichi_soft.render.export import write_obj

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 0, 0], [6, 0, 0], [5, 1, 0]], np.float32)
    n = np.tile(np.float32([0, 0, 1]), (6, 1))
    tris = np.array([[0, 1, 2], [3, 4, 5]])
    write_obj(tmp_path / "m.obj", v, n, tris, np.array([0, 0, 0, 1, 1, 1], np.uint8))
    text = (tmp_path / "m.obj").read_text().splitlines()
    assert [line for line in text if line.startswith(("o ", "f "))] == ["o body_0", "f 1//1 2//2 3//3",
                                                                        "o body_1", "f 4//4 5//5 6//6"]


@pytest.mark.parametrize("args, word", [
    (["--video", "x.avi"], ".mp4 or .gif"),
    (["--video", "x.mp4", "--resolution", "97x64"], "even"),
    (["--resolution", "12x9000"], "WIDTHxHEIGHT"),
    (["--frames", "main.py"], "not a directory"),
    (["--video", "x.mp4", "--quality", "ultra"], "low', 'medium', 'high"),
])
def test_bad_render_flags_exit_2(args, word, tmp_path):
    (tmp_path / "main.py").write_text("")
    p = cli("run", "--duration", "0.1", *args, cwd=tmp_path)
    assert p.returncode == 2
    assert len(p.stderr.strip().splitlines()) == 1 and word in p.stderr, p.stderr


# -- building blocks ------------------------------------------------------------------------------
def test_grid_shape():
    from taichi_soft.render.compare import grid_shape

    assert grid_shape(1, 1280, 720) == (1, 1)
    assert grid_shape(2, 1280, 720) == (2, 1)
    assert grid_shape(3, 1280, 720) == (2, 2)
    assert grid_shape(4, 1280, 720) == (2, 2)
    assert grid_shape(6, 1280, 720) == (3, 2)


def test_staged_dir_replaces_only_its_own_files(tmp_path):
    from taichi_soft.render.outputs import StagedDir

    target = tmp_path / "frames"
    target.mkdir()
    for name in ("frame_00000.png", "frame_00001.png", "frame_00002.png", "notes.txt"):
        (target / name).write_text("old")
    staged = StagedDir(target, "frame", ".png")
    staged.file(0).write_text("new")
    assert (target / "frame_00000.png").read_text() == "old"  # nothing changes before commit
    staged.commit()
    assert sorted(f.name for f in target.iterdir()) == ["frame_00000.png", "notes.txt"]
    assert (target / "frame_00000.png").read_text() == "new"
    aborted = StagedDir(target, "frame", ".png")
    aborted.file(0).write_text("newer")
    aborted.abort()
    assert (target / "frame_00000.png").read_text() == "new" and len(list(tmp_path.iterdir())) == 1


def test_background_writer_reports_worker_failure():
    from taichi_soft.render.outputs import BackgroundWriter

    done = []

    def handle(item):
        if item == 3:
            raise OSError("disk full")
        done.append(item)

    writer = BackgroundWriter(handle, maxsize=2)
    with pytest.raises(OSError, match="disk full"):
        for k in range(100):
            writer.submit(k)
        writer.close()
    assert done == [0, 1, 2]
