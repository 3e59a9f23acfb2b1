"""The key light's shadows and the bodies' supersampled edges for the Taichi rasterizer.

Shadow map: the bodies are drawn by the same rasterizer (``raster.TaichiRasterizer``) from the
key light (a point light, ``lighting.light_rig``) through a square perspective view aimed at the
bodies' bounding box, keeping only the triangles that face *away* from the light (``cull =
"front"``): the map holds the casters' far sides. A lit surface of a body is then always a body's
thickness in front of what the map holds (no acne without a large bias), and the terrain is not
in the map at all (it never shadows itself, so it cannot have acne); the bias only has to cover
the map's own sampling. At a contact the far side meets the terrain, so the shadow reaches the
contact up to that bias (2.5 cm on the default 4 m cube: no gap on screen). ``raster._lit`` reads the map with 2 x 2 percentage-closer
filtering, which antialiases the shadow's edge.

A body's triangles turned away from the light are in its own shadow by geometry: the rasterizer
draws them without the key light's share (``draw(..., light=)``) and they skip the map, where
they are themselves at a depth too steep to compare (the stripes, acne, a bias cannot remove on
faces nearly edge-on to the light). Their smooth vertex normals would otherwise still give them
key light near an edge; this way a cube's far faces are dark, as a real cube's are. Within a
cosine of ``raster.TERMINATOR`` of grazing, on either side, the shadow's effect fades to nothing,
so a curved body's terminator shows neither the map's texels nor its own facets.

Per frame only the pixels where a shadow can be are looked up (``rect``): the screen box of the
bodies' bounding box and of its corners pushed away from the light until they pass the terrain.
The bodies' own pass (``BodyPass``, 2 x 2 samples a pixel at high quality) likewise touches
only the bodies' screen box.

Pure numpy apart from the rasterizers it owns.
"""
from __future__ import annotations

import math

import numpy as np

from .camera import CameraSpec, project, projection_matrix, view_matrix

MAP_SIZE = 512  # shadow map texels a side; around the default 4 m cube: 1.7 cm a texel
BIAS_TEXELS = 1.5  # depth bias, towards the light [texels of the map at the casters' far side]
MARGIN = 1.1  # the light's view reaches this much beyond the casters' bounding sphere


def _box_corners(lo, hi) -> np.ndarray:
    return np.array([[(lo, hi)[i & 1][0], (lo, hi)[(i >> 1) & 1][1], (lo, hi)[(i >> 2) & 1][2]] for i in range(8)])


def screen_rect(points, cam: CameraSpec, width: int, height: int) -> np.ndarray:
    """(col0, row0, col1, row1) [px], half-open, of the pixels that can see ``points`` [m]' convex
    hull (one pixel of margin); the whole image when any point is behind the camera."""
    pix = project(points, cam, width, height)
    if not np.all(np.isfinite(pix)):
        return np.array([0, 0, width, height], np.int32)
    lo = np.floor(pix.min(axis=0)) - 1
    hi = np.ceil(pix.max(axis=0)) + 2
    return np.array([max(lo[0], 0), max(lo[1], 0), min(hi[0], width), min(hi[1], height)], np.int32)


def pixel_to_light(cam: CameraSpec, width: int, height: int, light_cam: CameraSpec, size: int) -> np.ndarray:
    """3 x 4 matrix taking (px w, py w, w, 1) of the image (pixel coordinates px, py, view depth w
    [m]) to the homogeneous pixel coordinates (x w', y w', w') of a ``size`` x ``size`` map seen
    by ``light_cam`` (the raster's own convention: row 0 at the top, w' its view depth)."""
    p = projection_matrix(cam, width / height)
    to_view = np.array([[2 / (width * p[0, 0]), 0, -1 / p[0, 0], 0],
                        [0, -2 / (height * p[1, 1]), 1 / p[1, 1], 0],
                        [0, 0, -1, 0],
                        [0, 0, 0, 1]])
    to_map = np.array([[0.5 * size, 0, 0, 0.5 * size], [0, -0.5 * size, 0, 0.5 * size], [0, 0, 0, 1.0]])
    light = projection_matrix(light_cam, 1.0) @ view_matrix(light_cam)
    return to_map @ light @ np.linalg.inv(view_matrix(cam)) @ to_view


def shadow_reach(corners, light, kind: str, params: dict) -> np.ndarray:
    """Where the rays from the point ``light`` through ``corners`` [m] leave the terrain's reach:
    on a plane the point where they meet it, on a sphere or bowl a point beyond the ball; None when
    a ray misses a plane (it leaves the image's bound to the whole frame)."""
    light = np.asarray(light, dtype=np.float64)
    d = corners - light
    if kind in ("plane", "tilted_plane"):
        n = np.asarray(params["normal"], dtype=np.float64)
        n = n / np.linalg.norm(n)
        denom = d @ n
        if np.any(denom > -1e-9):
            return None
        t = ((np.asarray(params["point"], dtype=np.float64) - light) @ n) / denom
        return light + np.maximum(t, 1.0)[:, None] * d
    if kind in ("sphere", "bowl"):
        c = np.asarray(params["center"], dtype=np.float64)
        length = np.linalg.norm(corners - c, axis=1) + float(params["radius"])
        return corners + d / np.linalg.norm(d, axis=1, keepdims=True) * length[:, None]
    return corners  # no terrain: only the bodies receive, inside their own box


class ShadowPass:
    """The key light's shadow map for one frame (``prepare``) and what ``raster.finish`` needs to
    read it: ``matrix``, ``bias`` and ``body_bias`` [m], ``rect``; ``raster``, the map's rasterizer."""

    def __init__(self, size: int = MAP_SIZE):
        from .raster import TaichiRasterizer

        self.size = int(size)
        self.raster = TaichiRasterizer(self.size, self.size)
        self.matrix = np.zeros((3, 4), np.float32)
        self.bias = self.body_bias = 0.0
        self.rect = np.zeros(4, np.int32)
        self.drawn = False

    def prepare(self, cam: CameraSpec, width: int, height: int, key_light, lo, hi, kind: str, params: dict) -> bool:
        """Aim the map at the casters' bounding box ``lo``, ``hi`` [m] from ``key_light`` [m] and start
        it (``raster.begin``); False (no shadow this frame) when the light is inside the box's
        bounding sphere. Then draw the casters with ``cast`` and pass this to ``finish``."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        center, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo)) + 1e-3
        key_light = np.asarray(key_light, dtype=np.float64)
        dist = float(np.linalg.norm(center - key_light))
        if dist <= MARGIN * radius:
            return False
        half = math.asin(MARGIN * radius / dist)
        axis = (center - key_light) / dist
        up = (0.0, 1.0, 0.0) if abs(axis[1]) < 0.9 else (0.0, 0.0, 1.0)
        light_cam = CameraSpec(tuple(key_light), tuple(center), up, math.degrees(2 * half))
        self.matrix = pixel_to_light(cam, width, height, light_cam, self.size).astype(np.float32)
        texel = 2 * (dist + radius) * math.tan(half) / self.size  # [m] at the casters' far side
        self.bias = self.body_bias = BIAS_TEXELS * texel
        corners = _box_corners(lo, hi)
        reach = shadow_reach(corners, key_light, kind, params)
        if reach is None:
            self.rect = np.array([0, 0, width, height], np.int32)
        else:
            self.rect = screen_rect(np.concatenate([corners, reach]), cam, width, height)
        self.raster.begin(light_cam, (0.0, 0.0, 0.0))
        self.drawn = True
        return True

    def cast(self, vertices, indices, colors):
        """Draw a closed caster's far side (as seen from the light) into the map."""
        self.raster.draw(vertices, indices, colors, cull="front")

    def clear(self):
        """Reset the map after the frame's ``finish``."""
        if self.drawn:
            self.raster.clear()
            self.drawn = False


class BodyPass:
    """The bodies drawn apart from the terrain, at ``factor`` times the image's width and height
    (``factor`` x ``factor`` samples a pixel; 2 antialiases their silhouettes), inside ``rect``
    [px of the image], their screen box; ``raster.finish`` composites, averages and resets them.
    Drawn apart, the terrain's own image can be kept from frame to frame while the camera holds."""

    def __init__(self, width: int, height: int, factor: int):
        from .raster import TaichiRasterizer

        self.factor = int(factor)
        self.raster = TaichiRasterizer(self.factor * int(width), self.factor * int(height))
        self.width, self.height = int(width), int(height)
        self.rect = np.zeros(4, np.int32)

    def prepare(self, cam: CameraSpec, background, lo, hi):
        self.rect = screen_rect(_box_corners(np.asarray(lo), np.asarray(hi)), cam, self.width, self.height)
        self.raster.begin(cam, background)
