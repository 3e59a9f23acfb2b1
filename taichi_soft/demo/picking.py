"""From the cursor to the body: the view ray under a pixel, the particle it hits, the drag point.

A press picks on the drawn surface first (the triangle the ray crosses first, its nearest corner:
``surface_pick``, on the device); a ray that misses the surface but passes close to a particle
(just outside an edge or a corner) picks the particle nearest the ray (``pick``).

Pure numpy (no window): the camera is a ``render.camera.CameraSpec`` (GGUI's conventions: vertical
``fov``, the image spanning the whole window), the cursor GGUI's ``get_cursor_pos()`` (u, v) in
[0, 1], v up.
"""
from __future__ import annotations

import math

import numpy as np

PICK_RADIUS = 0.75  # lattice spacings: a ray through any point of a lattice face passes this close
# to one of the face's corner particles (half the diagonal is 0.71 spacings)


def _cross(a, b) -> tuple:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _unit(a) -> tuple:
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return (a[0] / n, a[1] / n, a[2] / n)


def view_ray(cam, u: float, v: float, aspect: float) -> tuple[np.ndarray, np.ndarray]:
    """(origin [m], unit direction) of the ray through cursor (u, v) of a window of ``aspect``
    = width / height, for camera ``cam``. (Plain floats for the 3-vectors: numpy's per-call
    overhead made this a quarter of a press frame's picking.)"""
    eye = tuple(float(c) for c in cam.position)
    forward = _unit([float(a) - e for a, e in zip(cam.lookat, eye)])
    right = _unit(_cross(forward, [float(c) for c in cam.up]))
    up = _cross(right, forward)
    half = math.tan(math.radians(cam.fov) / 2)
    a, b = (2 * u - 1) * half * aspect, (2 * v - 1) * half
    d = _unit([f + a * r + b * w for f, r, w in zip(forward, right, up)])
    return np.array(eye), np.array(d)


def pick(points: np.ndarray, origin: np.ndarray, direction: np.ndarray, radius: float) -> int | None:
    """The particle of ``points`` [n, 3] nearest the ray, of those within ``radius`` [m] of it and
    in front of its origin (a cursor just outside the silhouette, on an edge or a corner, picks
    that edge or corner). None if the ray passes every particle farther than ``radius``."""
    rel = points - origin
    depth = rel @ direction
    miss2 = np.einsum("ij,ij->i", rel, rel) - depth * depth
    hit = (depth > 0) & (miss2 <= radius * radius)
    if not hit.any():
        return None
    candidates = np.flatnonzero(hit)
    return int(candidates[np.argmin(miss2[candidates])])


def plane_point(origin: np.ndarray, direction: np.ndarray, point: np.ndarray, normal: np.ndarray) -> np.ndarray | None:
    """Where the ray meets the plane through ``point`` with ``normal``; None if it runs parallel to
    the plane or the plane is behind the ray's origin."""
    denom = float(np.dot(direction, normal))
    if abs(denom) < 1e-9:
        return None
    t = float(np.dot(np.subtract(point, origin), normal)) / denom
    return None if t <= 0 else origin + t * direction


def lattice_spacing(model) -> float:
    """The finest rest spacing [m] between neighbouring particles over the model's bodies."""
    return min(b.spec.size / (b.spec.n - 1) for b in model.bodies)
