"""The light rig and per-vertex lighting: GGUI's Lambertian model evaluated once per vertex.

GGUI's mesh fragment shader (Taichi 1.7.4, ``shaders/Mesh_vk.frag``) computes, per pixel,

    colour = ambient * c + sum over point lights of  f * c * light,
    f = max(dot(l, n), 0)   (two-sided meshes: |dot(l, n)|),

with ``l`` the unit direction from the pixel's surface point to the light and ``n`` the
interpolated normal; no specular term, no attenuation. On a GPU that is free; on Mesa's lavapipe
every point light adds 15-20 ms to a 1280 x 720 frame (docs/benchmarks/RENDERING.md). ``shade`` evaluates
the same formula at every vertex in one Taichi kernel, and the mesh is then drawn with an
ambient light of 1 and no point light, so the fragment stage only interpolates colours
(Gouraud shading). On surfaces cut fine enough (1 m terrain tiles, lights tens of metres away,
10 x 10 body faces) the two differ by a few 8-bit levels (tests/test_render.py measures it).
The Taichi rasterizer (``raster.py``) draws the same lit vertex colours.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

AMBIENT = (0.30, 0.30, 0.32)
KEY_LIGHT = (0.72, 0.70, 0.66)  # warm, above and left of the camera
FILL_LIGHT = (0.18, 0.20, 0.24)  # cool, from the other side: faces turned away stay readable


@dataclass(frozen=True)
class LightRig:
    """Ambient colour and two point lights (positions [m], colours), all linear RGB."""

    ambient: tuple
    key_position: tuple
    key_color: tuple
    fill_position: tuple
    fill_color: tuple


def light_rig(spec) -> LightRig:
    """The lights for camera ``spec`` (a ``CameraSpec``): ambient, a warm key light above and left
    of the camera and a cool fill light from the other side, at the camera's distance from its
    target. They move with the camera, so every scene and every follow shot is lit the same way."""
    eye, target = np.asarray(spec.position, dtype=np.float64), np.asarray(spec.lookat, dtype=np.float64)
    back = eye - target
    dist = np.linalg.norm(back)
    right = spec.right()
    up = np.asarray(spec.up, dtype=np.float64) / np.linalg.norm(spec.up)
    key = target + back + dist * (0.9 * up - 0.5 * right)
    fill = target + 0.6 * back + dist * (0.8 * right - 0.2 * up)
    return LightRig(AMBIENT, tuple(map(float, key)), KEY_LIGHT, tuple(map(float, fill)), FILL_LIGHT)


@ti.func
def _diffuse(p, n, light_pos, two_sided):
    d = (light_pos - p).normalized().dot(n)
    return ti.abs(d) if two_sided else ti.max(d, 0.0)


vec3f = ti.types.vector(3, ti.f32)


@ti.func
def _luminance(c):
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


@ti.kernel
def _shade(vertices: ti.template(), normals: ti.template(), base: ti.template(), out: ti.template(),
           share: ti.template(), ambient: vec3f, key_pos: vec3f, key_col: vec3f, fill_pos: vec3f, fill_col: vec3f,
           two_sided: ti.i32):
    for v in vertices:
        # eps: a degenerate vertex with a zero normal gets ambient light only, not NaN.
        p, n, c = vertices[v], normals[v].normalized(1e-20), base[v]
        key = c * _diffuse(p, n, key_pos, two_sided) * key_col
        result = c * (ambient + _diffuse(p, n, fill_pos, two_sided) * fill_col) + key
        # The colour attachment saturates at 1 per pixel; clamping per vertex keeps interpolated
        # colours inside the same range.
        out[v] = ti.min(result, 1.0)
        # What a shadow takes away: the key light's part of the (unclamped) luminance.
        share[v] = ti.min(_luminance(key) / ti.max(_luminance(result), 1e-6), 1.0)


def shade(vertices, normals, base, out, share, rig: LightRig, two_sided: bool = False):
    """Light every vertex: ``out[v]`` = GGUI's Lambertian colour of a surface point at
    ``vertices[v]`` [m] with unit normal ``normals[v]`` and base colour ``base[v]`` (f32 vec3
    fields of one length), under ``rig``; ``share[v]`` (f32 field, in [0, 1]) = the key light's
    fraction of that colour's luminance, which a shadow removes (``raster.py``). ``two_sided``:
    faces lit from behind as from the front."""
    _shade(vertices, normals, base, out, share, rig.ambient, rig.key_position, rig.key_color, rig.fill_position,
           rig.fill_color, int(two_sided))


def apply_rig_to_ggui(scene, rig: LightRig):
    """Set ``rig`` as a GGUI scene's lights (the per-pixel path, kept for reference renders)."""
    scene.ambient_light(rig.ambient)
    scene.point_light(rig.key_position, rig.key_color)
    scene.point_light(rig.fill_position, rig.fill_color)
