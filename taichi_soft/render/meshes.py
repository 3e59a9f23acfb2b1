"""Triangle meshes to draw: the terrain (numpy, built once) and the bodies' surfaces (on the device).

Terrain meshes match the collision shapes of ``taichi_soft.sim.contact.terrain`` exactly: vertices lie on the
plane / sphere / bowl surface, normals are the analytic ones. A plane is infinite, so it is drawn
as a finite checkerboard square around where the bodies can get to within the run.

``SurfaceMesh`` holds every body's outer surface (the lattice's outward-wound boundary
triangles) with its own compact vertex numbering; ``update(x)`` gathers the surface particles'
positions and recomputes smooth vertex normals on the device each frame.
"""

import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from .camera import plane_basis

# Colours (linear RGB in [0, 1]); GGUI writes them to the image without gamma.
CHECKER = ((0.78, 0.80, 0.82), (0.64, 0.67, 0.71))  # terrain tiles, low contrast against aliasing
SHELL = ((0.70, 0.80, 0.86), (0.58, 0.68, 0.76))  # the bowl, blue-grey
BODY_COLORS = ((0.95, 0.45, 0.15), (0.15, 0.65, 0.75), (0.60, 0.35, 0.80), (0.35, 0.70, 0.30), (0.90, 0.75, 0.15))


@dataclass
class TriMesh:
    """A static triangle mesh: vertices [n, 3] m, unit normals [n, 3], per-vertex colours [n, 3],
    triangles [m, 3] vertex indices wound counter-clockwise seen from the normal's side.

    GGUI culls no faces; ``two_sided`` lights a face seen from behind with its normal flipped.
    ``closed``: the surface encloses a volume, so faces seen from behind are always hidden (the
    Taichi rasterizer skips them).
    """

    vertices: np.ndarray
    normals: np.ndarray
    colors: np.ndarray
    triangles: np.ndarray
    two_sided: bool = False
    closed: bool = False
    checker_tile: int = 0  # cells per checker tile (``_checker_grid``); 0: not a checkerboard


def _checker_grid(position, normal, nu: int, nv: int, colors, tile: int = 1, two_sided=False) -> TriMesh:
    """A (u, v) in [0, 1]^2 surface cut into nu x nv cells, coloured as a checkerboard of
    ``tile`` x ``tile`` cell squares (fine cells keep curved shapes exact, tiles stay readable).

    ``position(u, v)`` and ``normal(u, v)`` take arrays and return [..., 3]. Cells do not share
    vertices so that each cell keeps one flat colour.
    """
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i, j = i.ravel(), j.ravel()
    corners = [(0, 0), (1, 0), (1, 1), (0, 1)]
    u = np.stack([(i + a) / nu for a, _ in corners], axis=1)  # [cells, 4]
    v = np.stack([(j + b) / nv for _, b in corners], axis=1)
    flat_v = position(u, v).reshape(-1, 3)
    flat_n = np.broadcast_to(normal(u, v), u.shape + (3,)).reshape(-1, 3)
    base = 4 * np.arange(len(i))[:, None]
    tris = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]])
    # Wind each triangle counter-clockwise as seen from its normal's side, whatever the
    # parametrisation's orientation, so exporters and any culling agree on the front.
    face_n = np.cross(flat_v[tris[:, 1]] - flat_v[tris[:, 0]], flat_v[tris[:, 2]] - flat_v[tris[:, 0]])
    flip = np.einsum("ij,ij->i", face_n, flat_n[tris].sum(axis=1)) < 0
    tris[flip] = tris[flip][:, ::-1]
    parity = ((i // tile + j // tile) % 2).repeat(4)
    cols = np.asarray(colors, dtype=np.float64)[parity]
    return TriMesh(flat_v, flat_n, cols, tris, two_sided, checker_tile=tile)


def plane_mesh(point, normal, focus, half_size: float) -> TriMesh:
    """Square of side 2 ``half_size`` [m] on the plane, centred where ``focus`` [m] projects.

    Tiles of 1 m (2, 4 ... m on very large squares) are anchored to ``point``, so they stay put
    in the world wherever the square is cut and show how far a body moves.
    """
    n, a, b = plane_basis(normal)
    p = np.asarray(point, dtype=np.float64)
    cell = 1.0 if half_size <= 40 else 2.0 ** math.ceil(math.log2(half_size / 40))
    f = np.asarray(focus, dtype=np.float64) - p
    # Snap the square's corner to the tile grid so the checker pattern is anchored at ``point``.
    ca = math.floor((np.dot(f, a) - half_size) / cell) * cell
    cb = math.floor((np.dot(f, b) - half_size) / cell) * cell
    cells = int(math.ceil(2 * half_size / cell))
    side = cells * cell

    def position(u, v):
        return p + (ca + u[..., None] * side) * a + (cb + v[..., None] * side) * b

    return _checker_grid(position, lambda u, v: n, cells, cells, CHECKER)


def _sphere_patch(center, radius, lat_lo, lat_hi, n_lon, n_lat, inward, colors, tile, two_sided=False) -> TriMesh:
    """Part of a sphere between latitudes ``lat_lo`` and ``lat_hi`` [rad] (0 = equator)."""
    c = np.asarray(center, dtype=np.float64)
    sign = -1.0 if inward else 1.0

    def direction(u, v):
        lon = 2 * math.pi * u
        lat = lat_lo + (lat_hi - lat_lo) * v
        return np.stack([np.cos(lat) * np.cos(lon), np.sin(lat), np.cos(lat) * np.sin(lon)], axis=-1)

    return _checker_grid(lambda u, v: c + radius * direction(u, v), lambda u, v: sign * direction(u, v),
                         n_lon, n_lat, colors, tile, two_sided)


def sphere_mesh(center, radius) -> TriMesh:
    """The whole ball, seen from outside. 96 x 48 cells: the flat facets sag at most
    r (1 - cos(pi / 96)) = 0.05 % of r below the true sphere the bodies rest on."""
    ball = _sphere_patch(center, radius, -math.pi / 2, math.pi / 2, 96, 48, False, CHECKER, tile=4)
    ball.closed = True
    return ball


def bowl_mesh(center, radius) -> TriMesh:
    """The bowl's lower hemisphere as one two-sided shell, normals pointing into the bowl.

    (Two coincident one-sided shells would z-fight: GGUI does not cull back faces.)
    """
    return _sphere_patch(center, radius, -math.pi / 2, 0.0, 96, 24, True, SHELL, tile=2, two_sided=True)


def plane_half_size(scene_data: dict, normal) -> float:
    """Half side [m] of the drawn plane: as far as a body could get along it within the run.

    Bound: start speed times duration plus free sliding under the in-plane part of gravity
    (frictionless), plus the body's size and a 40 m margin so the far edge stays in the distance;
    capped at 1 km.
    """
    duration = scene_data["sim"]["duration"]
    g = np.asarray(scene_data["sim"]["gravity"], dtype=np.float64)
    n = plane_basis(normal)[0]
    g_along = np.linalg.norm(g - np.dot(g, n) * n)
    reach = max(np.linalg.norm(b["velocity"]) * duration + b["size"] for b in scene_data["body"])
    return float(min(40.0 + reach + 0.5 * g_along * duration**2, 1000.0))


def terrain_meshes(kind: str, params: dict, scene_data: dict) -> list[TriMesh]:
    """The meshes that draw a terrain of ``kind`` with geometry ``params`` (``Terrain.params()``:
    the live terrain's values, so a geometry changed at run time is drawn where it now is); none
    for ``kind = "none"``. ``scene_data`` only sizes the finite square a plane is drawn as (where
    the bodies start and how far they can get, ``plane_half_size``).
    """
    if kind in ("plane", "tilted_plane"):
        focus = np.mean([b["center"] for b in scene_data["body"]], axis=0)
        return [plane_mesh(params["point"], params["normal"], focus, plane_half_size(scene_data, params["normal"]))]
    if kind == "sphere":
        return [sphere_mesh(params["center"], params["radius"])]
    if kind == "bowl":
        return [bowl_mesh(params["center"], params["radius"])]
    return []


# -- the checker filtered for its footprint on screen -----------------------------------------
mat4f = ti.types.matrix(4, 4, ti.f32)
vec2f = ti.types.vector(2, ti.f32)
vec3f = ti.types.vector(3, ti.f32)


@ti.kernel
def _fade_checker(vertices: ti.template(), colors: ti.template(), out: ti.template(), mvp: mat4f, size: vec2f,
                  near: ti.f32, tiles_per_cell: ti.f32, mean: vec3f):
    for cell in range(vertices.shape[0] // 4):
        # Corners 0, 1 and 3 of the cell ((0, 0), (1, 0), (0, 1) in its (u, v)) on screen [px].
        pix = ti.Matrix.zero(ti.f32, 3, 2)
        behind = False
        for k in ti.static(range(3)):
            v = vertices[4 * cell + (0, 1, 3)[k]]
            c = mvp @ ti.Vector([v[0], v[1], v[2], 1.0], dt=ti.f32)
            if c[3] < near:
                behind = True
            w = ti.max(c[3], near)
            pix[k, 0] = (c[0] / w + 1.0) * 0.5 * size[0]
            pix[k, 1] = (1.0 - c[1] / w) * 0.5 * size[1]
        # J: pixels per cell along u and v (columns); J^-1: cells per pixel step.
        j = ti.Matrix([[pix[1, 0] - pix[0, 0], pix[2, 0] - pix[0, 0]], [pix[1, 1] - pix[0, 1], pix[2, 1] - pix[0, 1]]])
        det = j.determinant()
        keep = 1.0
        if not behind:
            keep = 0.0
            if ti.abs(det) > 1e-12:
                inv = j.inverse()
                # The pixel's footprint in tiles: the larger of its extents along u and v.
                foot = ti.max(ti.abs(inv[0, 0]) + ti.abs(inv[0, 1]), ti.abs(inv[1, 0]) + ti.abs(inv[1, 1]))
                keep = ti.min(ti.max(2.0 * (1.0 - foot * tiles_per_cell), 0.0), 1.0)
        for k in ti.static(range(4)):
            c = colors[4 * cell + k]
            out[4 * cell + k] = c if keep >= 1.0 else mean + keep * (c - mean)  # exact where kept


def fade_checker(vertices, colors, out, tile: int, mean, mvp, width: int, height: int):
    """A checkerboard's vertex colours as seen by a camera: ``out`` = ``colors`` faded towards
    their ``mean`` where a pixel's footprint covers more than half a tile.

    For each cell (4 consecutive vertices, as ``_checker_grid`` makes them) the Jacobian of its
    projection (``mvp``: world -> clip, images ``width`` x ``height`` px) gives the pixel's
    footprint ``f`` in tiles (its larger extent, ``tile`` cells a tile); the checker's contrast is
    kept in full for f <= 1/2 (tiles of 2 px or more: a period of 4 px, twice the Nyquist limit)
    and falls linearly to none at f = 1 (a period of 2 px, the Nyquist limit), so no checker
    frequency above the pixel's Nyquist limit is drawn. Cells reaching behind the camera keep
    their colour (they are the nearest, largest ones). GGUI draws the same colours.
    """
    from .camera import Z_NEAR

    _fade_checker(vertices, colors, out, np.asarray(mvp, np.float32), (float(width), float(height)), Z_NEAR,
                  1.0 / tile, tuple(float(c) for c in mean))


# -- bodies -------------------------------------------------------------------------------------
@ti.func
def smooth_normals(vertices: ti.template(), normals: ti.template(), indices: ti.template()):
    """Unit vertex normals of the triangle mesh (``vertices``, flat triangle corner ``indices``)
    into ``normals``, which the caller has zeroed: each the area-weighted mean of its triangles'
    normals (the unnormalised cross product is twice the area). Call at a kernel's top level."""
    for t in range(indices.shape[0] // 3):
        a, b, c = indices[3 * t], indices[3 * t + 1], indices[3 * t + 2]
        n = (vertices[b] - vertices[a]).cross(vertices[c] - vertices[a])
        normals[a] += n  # atomic: triangles sharing a vertex add concurrently
        normals[b] += n
        normals[c] += n
    for v in range(normals.shape[0]):
        length = normals[v].norm()
        if length > 0:
            normals[v] /= length


@ti.data_oriented
class SurfaceMesh:
    """Every body's outer surface on the device, in f32 (what GGUI draws and exporters write).

    Fields: ``vertices``, ``normals`` [n_vertices] vec3 (m, unit); ``indices`` [3 n_triangles]
    (triangle corners into ``vertices``, outward winding); ``vertex_particle`` [n_vertices] the
    model particle each vertex follows. ``bodies[b]`` = (first vertex, vertex count, first index,
    index count) of body b.
    """

    def __init__(self, model):
        particles, triangles, body_of, self.bodies = [], [], [], []
        nv = ni = 0
        for body in model.bodies:
            used, local = np.unique(body.surface, return_inverse=True)
            particles.append(used)
            triangles.append(local.reshape(-1, 3) + nv)
            self.bodies.append((nv, len(used), ni, local.size))
            body_of.append(np.full(len(used), len(self.bodies) - 1, np.int32))
            nv += len(used)
            ni += local.size
        self.n_vertices, self.n_triangles = nv, ni // 3
        self.triangles_np = np.concatenate(triangles).astype(np.int32)  # [n_triangles, 3]
        self.vertex_particle = ti.field(ti.i32, nv)
        self.vertex_particle.from_numpy(np.concatenate(particles).astype(np.int32))
        self.vertices = ti.Vector.field(3, ti.f32, nv)
        self.normals = ti.Vector.field(3, ti.f32, nv)
        self.indices = ti.field(ti.i32, 3 * self.n_triangles)
        self.indices.from_numpy(self.triangles_np.ravel())
        self.vertex_body = np.concatenate(body_of)  # [n_vertices] body index of each vertex

    @ti.kernel
    def update(self, x: ti.template()):
        """Copy the surface particles' positions from ``x`` and recompute vertex normals.

        A vertex normal is the area-weighted mean of its triangles' normals (the unnormalised
        cross product is twice the area): smooth shading that follows the body as it deforms.
        """
        for v in range(self.n_vertices):
            self.vertices[v] = ti.cast(x[self.vertex_particle[v]], ti.f32)
            self.normals[v] = ti.Vector([0.0, 0.0, 0.0], dt=ti.f32)
        smooth_normals(self.vertices, self.normals, self.indices)

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices [n_vertices, 3] m, normals [n_vertices, 3]) as float32 copies."""
        return self.vertices.to_numpy(), self.normals.to_numpy()
