"""The Taichi rasterizer (render/raster.py) against geometry worked out by hand; no Vulkan needed.

Camera: at the origin looking down -z, 90 degree vertical fov, 96 x 96 pixels, so a point
(x, y, z) lands on pixel column (1 + x / -z) * 48 and row (1 - y / -z) * 48.
"""
import numpy as np
import pytest
import taichi as ti

from taichi_soft.render.camera import CameraSpec

# Module fixtures hold Taichi objects across tests: one runtime for the module (conftest.py).
pytestmark = pytest.mark.taichi_shared

N = 96
CAM = CameraSpec((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 90.0)
BACKGROUND = (0.0, 0.0, 0.0)


@pytest.fixture(scope="module")
def raster():
    from taichi_soft.render.raster import TaichiRasterizer

    return TaichiRasterizer(N, N)


def mesh(vertices, triangles, colors):
    """f32 / i32 Taichi fields of a small mesh."""
    v = ti.Vector.field(3, ti.f32, len(vertices))
    c = ti.Vector.field(3, ti.f32, len(vertices))
    i = ti.field(ti.i32, 3 * len(triangles))
    v.from_numpy(np.asarray(vertices, np.float32))
    c.from_numpy(np.broadcast_to(np.asarray(colors, np.float32), (len(vertices), 3)).copy())
    i.from_numpy(np.asarray(triangles, np.int32).ravel())
    return v, i, c


def quad(x0, x1, y0, y1, z, color):
    """Rectangle facing +z (towards the camera), counter-clockwise seen from the camera."""
    return mesh([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], [[0, 1, 2], [0, 2, 3]], color)


def render(raster, *meshes, cull=False):
    raster.begin(CAM, BACKGROUND)
    for m in meshes:
        raster.draw(*m, cull=cull)
    return raster.finish()


def test_square_covers_the_pixels_whose_centres_it_contains(raster):
    # x, y in [-1, 1] at z = -2 -> pixel coordinates [24, 72]: centres 24.5 ... 71.5, 48 x 48 pixels.
    img = render(raster, quad(-1, 1, -1, 1, -2.0, (0.5, 0.25, 1.0)))
    covered = img.any(axis=-1)
    assert covered.sum() == 48 * 48
    assert covered[24:72, 24:72].all()
    assert (img[30, 30] == [128, 64, 255]).all()  # round(255 c), as GGUI's 8-bit colour attachment


def test_nearer_surface_wins_whatever_the_draw_order(raster):
    far = quad(-1, 1, -1, 1, -3.0, (0.0, 0.0, 1.0))
    near = quad(-0.5, 0.5, -0.5, 0.5, -2.0, (1.0, 0.0, 0.0))
    a, b = render(raster, far, near), render(raster, near, far)
    np.testing.assert_array_equal(a, b)
    assert (a[48, 48] == [255, 0, 0]).all()  # the near quad, centre
    assert (a[48, 33] == [0, 0, 255]).all()  # only the far quad: it spans pixels [32, 64], the near one [36, 60]


def test_floor_reaching_behind_the_camera_is_drawn_up_to_its_far_edge(raster):
    """A floor y = -1 from z = +5 (behind the camera) to z = -50: no clipping artefacts, every
    row below the far edge (row 48 + 48 / 50 = 48.96) is floor, every row above it is not."""
    floor = mesh([[-60, -1, 5], [60, -1, 5], [60, -1, -50], [-60, -1, -50]], [[0, 1, 2], [0, 2, 3]], (0.2, 0.8, 0.2))
    img = render(raster, floor)
    is_floor = (img == [51, 204, 51]).all(axis=-1)
    assert is_floor[49:].all()
    assert not is_floor[:48].any()


def test_colours_are_interpolated_in_perspective(raster):
    """A floor whose colour runs linearly with depth, red 0 at z = -1 to 1 at z = -21: a pixel
    shows the colour of the floor point its ray hits (screen-space interpolation would not)."""
    v, i, _ = mesh([[-30, -1, -1], [30, -1, -1], [30, -1, -21], [-30, -1, -21]], [[0, 1, 2], [0, 2, 3]], (0, 0, 0))
    c = ti.Vector.field(3, ti.f32, 4)
    c.from_numpy(np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0], [1, 0, 0]], np.float32))
    img = render(raster, (v, i, c))
    for row in (60, 70, 90):
        z = -1.0 / ((row + 0.5) / 48 - 1)  # the ray through the row's centre meets y = -1 at this z
        expected = 255 * (-1 - z) / 20
        assert abs(int(img[row, 48, 0]) - expected) <= 1, (row, img[row, 48], expected)


def test_cull_skips_triangles_seen_from_behind(raster):
    front = quad(-1, 1, -1, 1, -2.0, (1.0, 1.0, 1.0))
    v, i, c = front
    flipped = ti.field(ti.i32, 6)
    flipped.from_numpy(i.to_numpy().reshape(-1, 3)[:, ::-1].ravel().copy())
    assert render(raster, front, cull=True).any()
    assert not render(raster, (v, flipped, c), cull=True).any()
    assert render(raster, (v, flipped, c), cull=False).any()  # without culling both sides show
