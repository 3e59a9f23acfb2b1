"""Large, outlined text, rectangles and polylines for the GGUI canvas, as 2D triangles.

GGUI's ImGui panels use one fixed 13-pixel font, too small for students at the back of a room.
So the heads-up lines are rasterised with Pillow (the renderer's own font, ``overlay.font``),
turned into one rectangle per horizontal run of same-coloured pixels, and drawn with
``canvas.triangles``. A dark outline keeps the text readable over any part of the scene.
Plot lines become thin quads in the same batch, so the whole heads-up display is one draw call.

Coordinates: GGUI canvas space, x right and y *up*, both in [0, 1]; text positions are given in
pixels from the top-left corner, like everything else a user sees.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw

from ..render.overlay import font

OUTLINE = (0.05, 0.06, 0.08)


@lru_cache(maxsize=256)
def _runs(text: str, size: int, weight: str) -> tuple[np.ndarray, np.ndarray]:
    """Pixel runs of ``text`` rendered at ``size`` px with a 2 px outline.

    Returns (runs [n, 4] int: row, first column, last column + 1, class; class 0 = outline,
    1 = glyph) and the image size (width, height) in pixels. Cached: most lines repeat.
    """
    f = font(size, weight)
    stroke = max(1, size // 12)
    left, top, right, bottom = f.getbbox(text, stroke_width=stroke)
    w, h = right - min(left, 0) + 1, bottom - min(top, 0) + 1
    img = Image.new("L", (max(w, 1), max(h, 1)), 0)
    # Glyph pixels 255, outline 128, background 0: each pixel is classified by its nearest level.
    ImageDraw.Draw(img).text((-min(left, 0), -min(top, 0)), text, font=f, fill=255, stroke_width=stroke,
                             stroke_fill=128)
    level = np.asarray(img)
    cls = np.where(level > 191, 2, np.where(level > 64, 1, 0))
    runs = []
    for row in range(cls.shape[0]):
        line = cls[row]
        change = np.flatnonzero(np.diff(line)) + 1
        starts = np.concatenate([[0], change])
        ends = np.concatenate([change, [len(line)]])
        for s, e in zip(starts, ends):
            if line[s]:
                runs.append((row, s, e, line[s] - 1))
    return np.asarray(runs, dtype=np.int32).reshape(-1, 4), np.array([w, h])


def text_size(text: str, size: int, weight: str = "regular") -> tuple[int, int]:
    """(width, height) in pixels of ``text`` drawn by ``Batch2D.text``."""
    return tuple(int(v) for v in _runs(text, size, weight)[1])


class Batch2D:
    """Collects one frame's 2D overlay; ``triangles()`` gives the vertices and colours to draw.

    ``window`` = (width, height) of the canvas in pixels.
    """

    def __init__(self, window: tuple[int, int]):
        self.width, self.height = window
        self._verts: list[np.ndarray] = []
        self._colors: list[np.ndarray] = []

    def text(self, text: str, x: float, y: float, size: int, color=(1.0, 1.0, 1.0), weight: str = "regular"):
        """Draw ``text`` with its top-left corner at pixel (x, y) from the window's top left."""
        runs, _ = _runs(text, size, weight)
        if not len(runs):
            return
        x0 = x + runs[:, 1]
        x1 = x + runs[:, 2]
        y0 = y + runs[:, 0]
        y1 = y0 + 1
        self._quads(x0, y0, x1, y1, np.where(runs[:, 3:4] == 1, color, OUTLINE))

    def rect(self, x0: float, y0: float, x1: float, y1: float, color):
        """A filled rectangle between pixel corners (x0, y0) and (x1, y1), top-left origin."""
        self._quads(np.array([x0]), np.array([y0]), np.array([x1]), np.array([y1]), np.array([color], float))

    def polyline(self, points, color, width: float = 2.0):
        """Connected segments through ``points`` [n, 2] (pixels, top-left origin), ``width`` px."""
        p = np.asarray(points, dtype=np.float64)
        if len(p) < 2:
            return
        a, b = p[:-1], p[1:]
        d = b - a
        length = np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
        off = 0.5 * width * np.c_[-d[:, 1:2], d[:, 0:1]] / length
        quad = np.stack([a + off, b + off, b - off, a + off, b - off, a - off], 1)  # [segments, 6, 2]
        u = quad[..., 0] / self.width
        v = 1.0 - quad[..., 1] / self.height
        self._verts.append(np.stack([u, v], -1).reshape(-1, 2))
        self._colors.append(np.tile(np.asarray(color, float), (6 * len(a), 1)))

    def _quads(self, x0, y0, x1, y1, colors):
        u0, u1 = x0 / self.width, x1 / self.width
        v0, v1 = 1.0 - y0 / self.height, 1.0 - y1 / self.height  # canvas y points up
        corners = np.stack([np.stack([u0, v0], 1), np.stack([u1, v0], 1), np.stack([u1, v1], 1),
                            np.stack([u0, v0], 1), np.stack([u1, v1], 1), np.stack([u0, v1], 1)], 1)
        self._verts.append(corners.reshape(-1, 2))
        self._colors.append(np.repeat(np.asarray(colors, float), 6, axis=0))

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices [6 n, 2] float32 canvas coordinates, colours [6 n, 3] float32), in draw order."""
        if not self._verts:
            return np.zeros((0, 2), np.float32), np.zeros((0, 3), np.float32)
        return (np.concatenate(self._verts).astype(np.float32), np.concatenate(self._colors).astype(np.float32))
