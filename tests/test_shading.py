"""Shadows and anti-aliasing of the Taichi rasterizer (docs/rendering.md, "Shadows and anti-aliasing").

Answers worked out from the geometry: where the key light's rays through a cube's corners meet
the plane, how much light a shadow takes away, and what a checker looks like when each pixel
averages 4 x 4 samples of it.
"""
import numpy as np
import pytest

from taichi_soft.render.camera import CameraSpec, projection_matrix, view_matrix

# Module fixtures hold Taichi objects across tests: one runtime for the module (conftest.py).
pytestmark = pytest.mark.taichi_shared

LUMA = np.array([0.2126, 0.7152, 0.0722])


def pixel_rays(cam: CameraSpec, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(eye [3], unit ray direction [height, width, 3]) through every pixel centre."""
    col, row = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    p = projection_matrix(cam, width / height)
    view = np.stack([(2 * col / width - 1) / p[0, 0], (1 - 2 * row / height) / p[1, 1], -np.ones_like(col)], axis=-1)
    world = view @ np.linalg.inv(view_matrix(cam))[:3, :3].T
    return np.asarray(cam.position, float), world / np.linalg.norm(world, axis=-1, keepdims=True)


def plane_hits(cam, width, height, y0: float) -> np.ndarray:
    """World point [height, width, 3] where each pixel's ray meets the plane y = y0 (NaN: it misses)."""
    eye, d = pixel_rays(cam, width, height)
    t = (y0 - eye[1]) / d[..., 1]
    t = np.where(t > 0, t, np.nan)
    return eye + t[..., None] * d


def cross2(a, b) -> float:
    """z of the cross product of two 2D vectors."""
    return a[0] * b[1] - a[1] * b[0]


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise hull of 2D points (monotone chain)."""
    pts = sorted(map(tuple, points))

    def half(seq):
        out = []
        for p in seq:
            while len(out) >= 2 and cross2(np.subtract(out[-1], out[-2]), np.subtract(p, out[-2])) <= 0:
                out.pop()
            out.append(p)
        return out[:-1]

    return np.array(half(pts) + half(pts[::-1]))


def signed_distance(hull: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Signed distance [m] of 2D points ``q`` [..., 2] to the convex polygon ``hull``: > 0 inside.
    Outside it is a lower bound of the true distance (the largest edge-line distance), enough to
    keep points clear of the edge."""
    d = np.full(q.shape[:-1], np.inf)
    for a, b in zip(hull, np.roll(hull, -1, axis=0)):
        e = b - a
        n = np.array([-e[1], e[0]]) / np.linalg.norm(e)  # inward for a counter-clockwise hull
        d = np.minimum(d, (q - a) @ n)
    return d


# -- shadows ---------------------------------------------------------------------------------------
W, H = 480, 270
SIZE = 4.0  # the plane scene's cube [m]
PLANE_Y = -1.0


TOP_VIEW = ([4, 28, 12], [0, 0, 0])  # from high up: the ground round the cube is in view
SIDE_VIEW = ([16, 7, 12], [0, 0, -2])  # lower: the key light lower too, so a lift moves the shadow more


def resting_cube(lift: float, camera=TOP_VIEW):
    """The plane scene's cube, axis-aligned and at rest, its bottom ``lift`` m above the plane,
    seen by ``camera`` = (position, look-at) [m]."""
    from taichi_soft.sim.integrators import names
    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import Simulation

    center = PLANE_Y + SIZE / 2 + lift
    scene = load_scene("plane", ["body.0.n=4", f"body.0.center=[0, {center}, 0]", "body.0.rotation.degrees=0",
                                 f"render.camera.position={camera[0]}", f"render.camera.lookat={camera[1]}"],
                       integrator_names=names())
    return Simulation(scene)


def shadow_frames(sim):
    """(frame with shadows, frame without, pixels of the cube, camera) at W x H."""
    from taichi_soft.render.camera import scene_camera
    from taichi_soft.render.renderer import SimulationView
    from taichi_soft.render.taichi_renderer import TaichiRenderer

    view = SimulationView(sim)
    cam = scene_camera(sim.scene.data, W / H)
    shadowed = TaichiRenderer(W, H, "medium").render(view, cam)
    plain = TaichiRenderer(W, H, "low").render(view, cam)
    view.show_surface = False
    bare = TaichiRenderer(W, H, "low").render(view, cam)
    cube = np.abs(plain.astype(int) - bare).max(axis=-1) > 0
    # Pixels next to the cube's image may mix it in: keep 2 pixels away.
    near_cube = cube.copy()
    for axis in (0, 1):
        for shift in (-2, -1, 1, 2):
            near_cube |= np.roll(cube, shift, axis=axis)
    return shadowed, plain, near_cube, cam


def analytic_shadow(sim, key):
    """Hull (x, z) of the cube's shadow on the plane: the key light's rays through its corners."""
    x = sim.state.x.to_numpy()
    lo, hi = x.min(axis=0), x.max(axis=0)
    corners = np.array([[(lo, hi)[i & 1][0], (lo, hi)[i >> 1 & 1][1], (lo, hi)[i >> 2 & 1][2]] for i in range(8)])
    t = (PLANE_Y - key[1]) / (corners[:, 1] - key[1])
    hits = key + t[:, None] * (corners - key)
    return convex_hull(hits[:, [0, 2]])


def key_share(points, cam):
    """The key light's share of the plane's luminance at ``points`` [..., 3] (what a shadow
    removes), from the light rig and the Lambertian model (``lighting.py``)."""
    from taichi_soft.render.lighting import light_rig

    rig = light_rig(cam)
    n = np.array([0.0, 1.0, 0.0])

    def diffuse(pos):
        l = np.asarray(pos) - points
        return np.maximum((l / np.linalg.norm(l, axis=-1, keepdims=True)) @ n, 0.0)

    key = diffuse(rig.key_position)[..., None] * rig.key_color
    rest = np.asarray(rig.ambient) + diffuse(rig.fill_position)[..., None] * rig.fill_color
    return (key @ LUMA) / ((key + rest) @ LUMA)


# Margin [m] kept from the analytic shadow's edge: a pixel at 480 x 270 spans ~0.1 m of the plane
# here, the map's 2 x 2 filter and its bias a few centimetres; 0.25 m keeps every tested pixel
# wholly on one side.
MARGIN = 0.25


@pytest.mark.parametrize("lift", [0.0, 1.0])
def test_cube_shadows_the_plane_where_the_key_light_says(lift):
    """Resting (lift 0) or 1 m up, the cube darkens exactly the plane pixels inside its analytic
    shadow, the one the key light's rays through its corners cast.

    Inside: the pixel keeps the plane's light less the key light's, so its luminance over the
    unshadowed frame's is 1 - (key share), computed here from the light rig; the tolerance, 2 %
    of that ratio, covers 8-bit colours (under 1 % at these levels, ~150) and the key share
    stored in 8 bits per pixel (0.4 %), while the shadow's own effect is a 40-60 % drop. Outside:
    the pixel is the unshadowed frame's exactly. A shadow in the wrong place (not moved by the
    lift) fails both; no shadow fails the first.
    """
    from taichi_soft.render.lighting import light_rig

    sim = resting_cube(lift, SIDE_VIEW)
    shadowed, plain, near_cube, cam = shadow_frames(sim)
    key = np.asarray(light_rig(cam).key_position)
    hits = plane_hits(cam, W, H, PLANE_Y)
    hull = analytic_shadow(sim, key)
    dist = signed_distance(hull, hits[..., [0, 2]])
    usable = np.isfinite(dist) & ~near_cube
    inside = usable & (dist > MARGIN)
    outside = usable & (dist < -MARGIN) & (dist > -3.0)  # beside the shadow
    assert inside.sum() >= 50 and outside.sum() >= 200, (inside.sum(), outside.sum())

    lum_s, lum_p = shadowed.astype(float) @ LUMA, plain.astype(float) @ LUMA
    ratio = lum_s[inside] / lum_p[inside]
    expected = 1.0 - key_share(hits[inside], cam)
    assert np.all(expected < 0.75)  # the margin a shadow makes: at least a quarter darker
    np.testing.assert_allclose(ratio, expected, rtol=0.02)
    np.testing.assert_array_equal(shadowed[outside], plain[outside])

    if lift:  # the shadow moved as the light's direction says: away from where the resting one was
        rest = resting_cube(0.0, SIDE_VIEW)
        moved = signed_distance(analytic_shadow(rest, key), hits[..., [0, 2]])
        left = usable & (moved > MARGIN) & (dist < -MARGIN)  # in the resting shadow, lit now
        entered = inside & (moved < -MARGIN)  # in the shadow now, lit at rest
        assert left.sum() >= 20 and entered.sum() >= 20, (left.sum(), entered.sum())


def test_contact_has_no_gap():
    """At rest, the plane right beside the cube's bottom edge on the shadow's side is dark: the
    shadow starts at the contact (the bias leaves no lit seam between the body and its shadow)."""
    from taichi_soft.render.lighting import light_rig

    sim = resting_cube(0.0)
    shadowed, plain, near_cube, cam = shadow_frames(sim)
    key = np.asarray(light_rig(cam).key_position)
    hits = plane_hits(cam, W, H, PLANE_Y)
    dist = signed_distance(analytic_shadow(sim, key), hits[..., [0, 2]])
    x = sim.state.x.to_numpy()
    lo, hi = x.min(axis=0), x.max(axis=0)
    # Plane pixels within 0.4 m of the cube's footprint, inside its shadow, not covered by it.
    gap = np.maximum(np.maximum(lo[0] - hits[..., 0], hits[..., 0] - hi[0]),
                     np.maximum(lo[2] - hits[..., 2], hits[..., 2] - hi[2]))
    ring = np.isfinite(dist) & (dist > MARGIN) & (gap > 0) & (gap < 0.4) & ~near_cube
    assert ring.sum() >= 5, ring.sum()
    lum_s, lum_p = shadowed.astype(float) @ LUMA, plain.astype(float) @ LUMA
    assert np.all(lum_s[ring] < 0.75 * lum_p[ring]), (lum_s[ring] / lum_p[ring]).max()


# -- the checker at a grazing angle ----------------------------------------------------------------
GW, GH = 160, 96
SS = 4  # the reference: 4 x 4 samples a pixel


def grazing_frames():
    """(filtered frame (``low``), point-sampled frame, 4 x 4 supersampled reference, camera, view,
    ``high`` frame) of the plane seen from 1.5 m above it, looking along it (bodies hidden; a
    fixed camera, so ``high`` supersamples the terrain)."""
    from taichi_soft.render.lighting import light_rig
    from taichi_soft.render.raster import TaichiRasterizer
    from taichi_soft.render.renderer import BACKGROUND, SimulationView
    from taichi_soft.render.taichi_renderer import TaichiRenderer
    from taichi_soft.sim.integrators import names
    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import Simulation

    scene = load_scene("plane", ["body.0.n=4", "render.camera.position=[0.3, 0.5, 20]",
                                 "render.camera.lookat=[0.3, -0.5, -20]"], integrator_names=names())
    sim = Simulation(scene)
    view = SimulationView(sim, surface=False)
    from taichi_soft.render.camera import scene_camera

    cam = scene_camera(scene.data, GW / GH)
    assert not cam.follow
    filtered = TaichiRenderer(GW, GH, "low").render(view, cam)
    high = TaichiRenderer(GW, GH, "high").render(view, cam)

    def raw(width, height):
        view.light(light_rig(cam))  # no viewport: the checker unfiltered
        r = TaichiRasterizer(width, height)
        r.begin(cam, BACKGROUND)
        for m in view.lit_meshes():
            r.draw(m.vertices, m.indices, m.colors, cull=m.closed)
        return r.finish()

    point = raw(GW, GH)
    fine = raw(SS * GW, SS * GH).astype(float)
    reference = fine.reshape(GH, SS, GW, SS, 3).mean(axis=(1, 3))
    return filtered, point, reference, cam, view, high


def test_checker_at_a_grazing_angle_has_nothing_above_nyquist():
    """Where a checker tile is under a pixel tall (its period under 2 pixels: above the Nyquist
    limit), the frame must show the 4 x 4 supersampled reference's near-uniform average, not a
    pattern.

    Bound: point sampling there picks one tile colour or the other, an error of half the checker's
    contrast C against the average (RMS ~ C / 2); the 4 x 4 reference itself still carries the
    sampling noise of 16 samples of such tiles (RMS up to C / 8). An RMS difference from the
    reference of at most C / 4 is only possible when the checker's above-Nyquist frequencies are
    gone; the unfiltered frame of the same view is checked to exceed it (the test can fail).
    """
    from taichi_soft.render.meshes import CHECKER

    filtered, point, reference, cam, view, high = grazing_frames()
    hits = plane_hits(cam, GW, GH, PLANE_Y)
    # A tile's height on screen at each pixel: 1 m / (metres of plane per pixel row).
    step = np.abs(np.diff(hits[..., 2], axis=0))
    tall = np.full((GH, GW), np.nan)
    tall[1:] = 1.0 / step
    square = view.terrain[0].vertices.to_numpy()
    inside = (np.isfinite(tall) & (hits[..., 0] > square[:, 0].min() + 1) & (hits[..., 0] < square[:, 0].max() - 1)
              & (hits[..., 2] > square[:, 2].min() + 1))
    far = inside & (tall < 1.0)
    assert far.sum() >= 300, far.sum()
    contrast = (np.subtract(*CHECKER) @ LUMA) * (reference[inside] @ LUMA).mean() / (np.mean(CHECKER, axis=0) @ LUMA)

    def rms(img):
        return float(np.sqrt(np.mean(((img.astype(float) - reference) @ LUMA)[far] ** 2)))

    assert rms(point) > contrast / 4, (rms(point), contrast)
    assert rms(filtered) <= contrast / 4, (rms(filtered), rms(point), contrast)
    assert rms(high) <= contrast / 4, (rms(high), rms(point), contrast)


def test_checker_keeps_its_contrast_where_tiles_are_large():
    """The filter only fades what is too small to draw: where tiles are 4 pixels tall or more the
    ``low`` frame equals the unfiltered one, and the ``high`` frame, whose terrain has 4 x 4
    samples a pixel, equals the 4 x 4 supersampled reference (to rounding: 1 level), tile edges
    included, where one sample a pixel leaves staircases (checked to differ)."""
    filtered, point, reference, cam, view, high = grazing_frames()
    hits = plane_hits(cam, GW, GH, PLANE_Y)
    tall = np.full((GH, GW), np.nan)
    tall[1:] = 1.0 / np.abs(np.diff(hits[..., 2], axis=0))
    near = np.isfinite(tall) & (tall >= 4.0)
    assert near.sum() >= 300, near.sum()
    np.testing.assert_array_equal(filtered[near], point[near])
    assert np.abs(point[near] - reference[near]).max() > 8  # the staircases of one sample a pixel
    assert np.abs(high[near] - reference[near]).max() <= 1.0, np.abs(high[near] - reference[near]).max()


# -- silhouettes -----------------------------------------------------------------------------------
def test_high_quality_bodies_match_a_supersampled_reference_on_their_edges():
    """At ``high`` each body pixel averages 2 x 2 samples: along the cube's silhouette the frame is
    closer to a 4 x 4 supersampled reference (the one-sample ``medium`` frame drawn at 4 times the
    size, averaged) than the one-sample frame is, by at least a third of its RMS error there
    (2 x 2 samples halve the coverage error of an edge pixel at worst: 1/2 -> 1/4 of a step)."""
    from taichi_soft.render.camera import scene_camera
    from taichi_soft.render.renderer import SimulationView
    from taichi_soft.render.taichi_renderer import TaichiRenderer

    sim = resting_cube(0.0)
    view = SimulationView(sim)
    w, h = 160, 96
    cam = scene_camera(sim.scene.data, w / h)
    one = TaichiRenderer(w, h, "medium").render(view, cam).astype(float)
    four = TaichiRenderer(w, h, "high").render(view, cam).astype(float)
    ref = TaichiRenderer(4 * w, 4 * h, "medium").render(view, cam).astype(float).reshape(h, 4, w, 4, 3).mean(axis=(1, 3))
    view.show_surface = False
    bare = TaichiRenderer(w, h, "low").render(view, cam).astype(float)
    view.show_surface = True
    low = TaichiRenderer(w, h, "low").render(view, cam).astype(float)
    cube = np.abs(low - bare).max(axis=-1) > 0
    ring = cube.copy()
    for axis in (0, 1):
        for shift in (-1, 1):
            ring |= np.roll(cube, shift, axis=axis)
    # The silhouette: pixels at the cube's image border where one sample misses the coverage.
    edge = ring & (ring & ~np.roll(cube, 1, 0) | ring & ~np.roll(cube, -1, 0) | ring & ~np.roll(cube, 1, 1)
                   | ring & ~np.roll(cube, -1, 1)) & (np.abs(one - ref).max(axis=-1) > 8)
    assert edge.sum() >= 20, edge.sum()

    def rms(img):
        return float(np.sqrt(np.mean(((img - ref) @ LUMA)[edge] ** 2)))

    assert rms(four) <= rms(one) * 2 / 3, (rms(four), rms(one))
