"""Cameras: the scene's ``[render.camera]``, per-terrain defaults that frame the action, and the
look-at / perspective matrices GGUI uses (so tests and tools can project points to pixels).

Pure numpy: nothing here needs Taichi or Vulkan.

Conventions (GGUI's): right-handed world, y up; ``fov`` is the *vertical* field of view in
degrees; pixel (0, 0) is the top-left corner of an image array ``img[row, col]``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

DEFAULT_FOV = 40.0  # degrees, vertical
Z_NEAR, Z_FAR = 0.1, 2000.0  # clipping planes [m]; far enough for a 200 m terrain quad

# Default viewing angles per terrain: (azimuth, elevation) in degrees. Azimuth turns from the
# viewer-facing direction of the terrain (+z for a level plane) towards +x (level plane) or
# uphill (tilted plane); elevation is measured from the terrain's plane (or the horizontal).
_VIEW_ANGLES = {
    "none": (30.0, 20.0),
    "plane": (30.0, 22.0),
    "tilted_plane": (-25.0, 30.0),
    "sphere": (30.0, 15.0),
    "bowl": (30.0, 42.0),
}
# Terrains where the bodies travel far (a 45-degree slope: 30 m in 4 s) get a camera that
# follows their centre of mass instead of a fixed wide shot in which the cube would be tiny.
_FOLLOW = {"tilted_plane", "sphere"}


@dataclass(frozen=True)
class CameraSpec:
    """A pinhole camera: ``position`` and ``lookat`` [m], ``up`` (any length), vertical ``fov`` [deg].

    With ``follow`` the camera keeps its offset ``position - lookat`` and re-aims at the bodies'
    centre of mass each frame (see ``following``).
    """

    position: tuple
    lookat: tuple
    up: tuple = (0.0, 1.0, 0.0)
    fov: float = DEFAULT_FOV
    follow: bool = False

    def right(self) -> np.ndarray:
        """Unit vector [world] pointing to the right of the image (view direction x ``up``)."""
        right = np.cross(-np.subtract(self.position, self.lookat), self.up)
        return right / max(np.linalg.norm(right), 1e-12)

    def following(self, center) -> "CameraSpec":
        """The camera moved so that it looks at ``center`` [m] from the same offset."""
        if not self.follow:
            return self
        c = np.asarray(center, dtype=np.float64)
        if not np.all(np.isfinite(c)):
            return self
        offset = np.subtract(self.position, self.lookat)
        return replace(self, position=tuple(c + offset), lookat=tuple(c))


# -- defaults ---------------------------------------------------------------------------------
def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _body_spheres(scene_data: dict) -> list[tuple[np.ndarray, float]]:
    """Bounding sphere (centre [m], radius [m]) of every body at rest."""
    return [(np.asarray(b["center"], dtype=np.float64), 0.5 * math.sqrt(3.0) * b["size"]) for b in scene_data["body"]]


def plane_basis(normal) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, level, uphill): the plane's unit normal and two unit in-plane directions.

    ``level`` is horizontal; ``uphill`` points up the slope. For a level plane they are +z and +x
    (so the default view of a level plane looks from +z, turned towards +x).
    """
    n = _unit(normal)
    level = np.cross(n, [0.0, 1.0, 0.0])
    if np.linalg.norm(level) < 1e-6:  # level plane (or upside down): any horizontal pair
        return n, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    level = _unit(level)
    uphill = _unit(np.cross(level, n))
    if uphill[1] < 0:
        uphill = -uphill
    # Seen from the ``level`` side, let the slope run down to the right of the image (the way a
    # level plane's +x does from +z): the image's right is (-level) x up.
    if np.dot(np.cross(-level, [0.0, 1.0, 0.0]), uphill) > 0:
        level = -level
    return n, level, uphill


def _fit_distance(spheres, center, direction, up, half_v: float, half_h: float) -> float:
    """Smallest camera distance from ``center`` along unit ``direction`` at which every sphere
    (centre [m], radius [m]) lies inside the view cone of half-angles ``half_v``, ``half_h`` [rad].

    Per sphere and image axis: its centre's offset from the view axis plus its radius widened by
    1 / cos(half-angle) (a sphere's silhouette off-axis) must fit in tan(half-angle) x depth.
    """
    right = np.cross(-direction, up)
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, -direction)
    distance = 0.0
    for c, r in spheres:
        rel = c - center
        z = np.dot(rel, direction)  # towards the camera
        for offset, half in ((abs(np.dot(rel, right)), half_h), (abs(np.dot(rel, cam_up)), half_v)):
            distance = max(distance, z + (offset + r / math.cos(half)) / math.tan(half), z + r + 2 * Z_NEAR)
    return distance


def default_camera(scene_data: dict, aspect: float, top_margin: float = 0.0) -> CameraSpec:
    """A camera for a scene without ``[render.camera]``: everything that matters is in frame.

    What matters, as spheres: the bodies at the start, and where they end up on the terrain (the
    footprint on a plane, the ball, the bowl). The camera looks at the middle of their bounding
    box from the terrain's default angles, at the least distance where all of them fit.
    ``aspect`` = width / height of the image; ``top_margin`` = fraction of the image height kept
    free at the top (for the text overlay): the action is fitted into the part below it.
    """
    terrain = scene_data["terrain"]
    kind = terrain["kind"]
    bodies = _body_spheres(scene_data)
    spheres = list(bodies)
    n, level, uphill = plane_basis(terrain.get("normal", [0.0, 1.0, 0.0]))
    if kind == "plane":
        p = np.asarray(terrain["point"], dtype=np.float64)
        # Where each body lands: its centre dropped onto the plane; it squashes and spreads.
        spheres += [(c - np.dot(c - p, n) * n, 1.3 * r) for c, r in bodies]
    elif kind in ("sphere", "bowl"):
        spheres.append((np.asarray(terrain["center"], dtype=np.float64), terrain["radius"]))
    elif kind == "tilted_plane":
        # Followed: frame one body's neighbourhood (it tumbles as it slides).
        spheres = [(c, 1.5 * r) for c, r in bodies]
    else:  # free bodies oscillate and spin about their start
        spheres = [(c, 1.2 * r) for c, r in bodies]
    lo = np.min([c - r for c, r in spheres], axis=0)
    hi = np.max([c + r for c, r in spheres], axis=0)
    center = 0.5 * (lo + hi)

    azimuth, elevation = (math.radians(a) for a in _VIEW_ANGLES[kind])
    if kind == "tilted_plane":
        frame_n, frame_a, frame_b = n, level, uphill
    else:  # level reference frame: elevation above the horizontal
        frame_n, frame_a, frame_b = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    direction = _unit(math.cos(elevation) * (math.cos(azimuth) * frame_a + math.sin(azimuth) * frame_b)
                      + math.sin(elevation) * frame_n)
    up = np.array([0.0, 1.0, 0.0])
    tan_v = math.tan(math.radians(DEFAULT_FOV) / 2)
    half_h = math.atan(tan_v * aspect)
    distance = _fit_distance(spheres, center, direction, up, math.atan(tan_v * (1 - top_margin)), half_h)
    # Raise the camera (and its aim) so the fitted action sits centred in the part below the margin.
    right = _unit(np.cross(-direction, up))
    shift = top_margin * tan_v * distance * np.cross(right, -direction)
    lookat = center + shift
    return CameraSpec(tuple(lookat + distance * direction), tuple(lookat), tuple(up), DEFAULT_FOV, kind in _FOLLOW)


def scene_camera(scene_data: dict, aspect: float, follow: bool | None = None, top_margin: float = 0.0) -> CameraSpec:
    """The scene's ``[render.camera]`` keys over the default camera; ``follow`` overrides tracking.

    A scene that sets any other camera key gets a fixed camera unless its ``follow`` key (or the
    ``follow`` argument) is true. ``top_margin`` only shapes the default camera (see ``default_camera``).
    """
    cam = default_camera(scene_data, aspect, top_margin)
    given = dict(scene_data["render"].get("camera", {}))
    follow_key = given.pop("follow", None)
    if given:
        cam = replace(cam, follow=False, **{k: (tuple(v) if isinstance(v, list) else float(v)) for k, v in given.items()})
    if follow_key is not None:
        cam = replace(cam, follow=bool(follow_key))
    if follow is not None:
        cam = replace(cam, follow=follow)
    return cam


# -- matrices ---------------------------------------------------------------------------------
def view_matrix(cam: CameraSpec) -> np.ndarray:
    """World -> camera 4x4 matrix (camera looks down -z, y up), column-vector convention."""
    eye = np.asarray(cam.position, dtype=np.float64)
    forward = _unit(np.subtract(cam.lookat, eye))
    right = _unit(np.cross(forward, cam.up))
    up = np.cross(right, forward)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = right, up, -forward
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def projection_matrix(cam: CameraSpec, aspect: float) -> np.ndarray:
    """Camera -> clip 4x4 perspective matrix (OpenGL convention, vertical ``fov``)."""
    f = 1.0 / math.tan(math.radians(cam.fov) / 2)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = f / aspect, f
    m[2, 2] = (Z_FAR + Z_NEAR) / (Z_NEAR - Z_FAR)
    m[2, 3] = 2 * Z_FAR * Z_NEAR / (Z_NEAR - Z_FAR)
    m[3, 2] = -1.0
    return m


def project(points, cam: CameraSpec, width: int, height: int) -> np.ndarray:
    """Pixel coordinates (col, row) of world ``points`` [m], shape [n, 3] -> [n, 2] float.

    Row 0 is the top of the image. Points behind the camera come back as NaN.
    """
    p = np.atleast_2d(np.asarray(points, dtype=np.float64))
    clip = (projection_matrix(cam, width / height) @ view_matrix(cam) @ np.c_[p, np.ones(len(p))].T).T
    w = clip[:, 3:4]
    ndc = np.where(w > 0, clip[:, :2] / np.where(w > 0, w, 1.0), np.nan)
    return np.c_[(ndc[:, 0] + 1) * 0.5 * width, (1 - ndc[:, 1]) * 0.5 * height]
