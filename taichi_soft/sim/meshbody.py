"""Soft bodies of any shape: a closed triangle mesh filled with the cube's particle lattice.

``mesh_lattice(path, n, size, scale)`` reads the mesh (OBJ, STL or PLY, with trimesh), scales it
so that its longest bounding-box side is ``size`` metres (or by ``scale`` metres per mesh unit),
lays a regular lattice of spacing h = side / (n - 1) over its bounding box (n points along the
longest side, as many as fit along the others, centred) and keeps the points inside the mesh
(trimesh's ray-parity point-in-mesh test). Springs are the cube's stencil (``lattice``: stretch,
shear, bend) between kept points; points left without springs and components too small to hold
together (fewer than ``MIN_COMPONENT`` particles) are dropped. Particles are numbered in lattice
(C) order and springs are ordered as ``lattice`` orders a cube's, so a cube given as a mesh makes
exactly the particles and springs of ``shape = "cube"``.

The result also embeds the input surface in the lattice (``embedding``): each mesh vertex is a
fixed weighted sum of particles, so the renderer and exporters draw the real surface as it
deforms (render/embedded.py). A vertex in a lattice cell with all 8 corners uses trilinear
weights; in a boundary cell that misses corners it uses the minimum-norm affine weights over the
16 particles nearest its cell's centre, which still reproduce its rest position exactly.

Everything here is host-side numpy (no Taichi); results are cached per file, size and n, so a
scene's validation, its memory check and the model builder read and fill the mesh once.
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import UserError
from .lattice import SPRING_KINDS, SPRING_OFFSETS

MESH_SUFFIXES = (".obj", ".stl", ".ply")
MIN_COMPONENT = 8  # particles: a connected piece smaller than one lattice cell's corners is dropped
# Ray direction of the point-in-mesh test: close to +z (a thin ray box, so trimesh's r-tree
# fallback stays cheap without Embree) but tilted so rays do not run along the axis-aligned
# edges and faces that lattice-aligned meshes (a cube) have.
_RAY_DIRECTION = np.array([0.13, 0.21, 1.0]) / np.linalg.norm([0.13, 0.21, 1.0])
# Test points are moved this fraction of h toward the box centre: a lattice point exactly on a
# face of the bounding box (every point of a cube's faces) is then inside, not "undefined".
_INWARD = 1e-3
NEAREST = 16  # particles a vertex of a boundary cell follows (module docstring)


@dataclass
class MeshLattice:
    """One mesh body's rest shape in its own frame (bounding-box centre at the origin), in metres.

    points [n_particles, 3]; grid [nx, ny, nz] particle index of each lattice point or -1;
    pairs [n_springs, 2] particle indices, kind [n_springs] (0 stretch, 1 shear, 2 bend) and
    rest [n_springs] lengths in ``lattice`` spring order; h spacing; vertices [nv, 3] and
    triangles [nt, 3] the input surface (outward winding); embed_index / embed_weight [nv, 8]
    (or [nv, NEAREST] when a vertex lies in a boundary cell, rows padded with weight 0) the
    particles and weights each vertex follows; mesh_volume [m^3]; dropped: particles dropped as
    too small pieces; notes: what was repaired or dropped.
    """

    path: Path
    h: float
    grid: np.ndarray
    points: np.ndarray
    pairs: np.ndarray
    kind: np.ndarray
    rest: np.ndarray
    vertices: np.ndarray
    triangles: np.ndarray
    embed_index: np.ndarray
    embed_weight: np.ndarray
    mesh_volume: float
    dropped: int = 0
    notes: list = field(default_factory=list)

    @property
    def n_particles(self) -> int:
        return len(self.points)

    @property
    def n_springs(self) -> int:
        return len(self.pairs)

    def spring_counts(self) -> tuple[int, int, int]:
        """(stretch, shear, bend) spring counts."""
        return tuple(int(c) for c in np.bincount(self.kind, minlength=len(SPRING_KINDS)))

    @property
    def extent(self) -> np.ndarray:
        """Side lengths [m] of the mesh's bounding box."""
        return self.vertices.max(axis=0) - self.vertices.min(axis=0)


def check_stl(path: Path) -> None:
    """Raise ``UserError`` unless ``path`` is an ASCII STL (text starting with ``solid``) or a binary
    one (an 80-byte header, a triangle count n and 50 bytes per triangle: 84 + 50 n bytes)."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(1024)
    if size >= 84 and 84 + 50 * int.from_bytes(head[80:84], "little") == size:
        return
    if head.lstrip().lower().startswith(b"solid") and b"\0" not in head:
        return
    count = int.from_bytes(head[80:84], "little") if size >= 84 else 0
    raise UserError(f"{str(path)!r}: not a valid STL file: it is not text starting with 'solid' (ASCII STL), "
                    f"and its {size} bytes do not match a binary STL (84 + 50 x {count} triangles)")


def load_mesh(path: Path):
    """The closed triangle mesh in ``path`` as a ``trimesh.Trimesh`` and a list of notes on what
    was repaired. Raises ``UserError`` (one line, starting with the path) for a missing,
    unreadable, unknown-format, empty or open mesh that trimesh cannot close."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise UserError(f"{str(path)!r}: unknown mesh format {path.suffix or '(no suffix)'!r}; "
                        f"use {', '.join(s[1:].upper() for s in MESH_SUFFIXES)}")
    if not path.is_file():
        raise UserError(f"{str(path)!r}: no such file")
    if not os.access(path, os.R_OK):
        raise UserError(f"{str(path)!r}: file is not readable")
    if path.suffix.lower() == ".stl":
        check_stl(path)
    try:
        # Unprocessed first: trimesh's processing drops non-finite vertices with their triangles, and
        # the user would hear of an open mesh instead of the bad coordinates.
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:  # noqa: BLE001 - trimesh raises many kinds on a malformed file
        raise UserError(f"{str(path)!r}: cannot read the mesh: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise UserError(f"{str(path)!r}: the file holds no triangles")
    bad = int((~np.isfinite(mesh.vertices)).any(axis=1).sum())
    if bad:
        raise UserError(f"{str(path)!r}: {bad} of the mesh's {len(mesh.vertices)} vertices have non-finite "
                        "coordinates (NaN or infinity)")
    mesh.process(validate=False)  # what trimesh.load(process=True) does: merge duplicate vertices
    notes = []
    if not mesh.is_watertight:
        trimesh.repair.fill_holes(mesh)
        if not mesh.is_watertight:
            raise UserError(f"{str(path)!r}: the mesh is not closed (it has open edges trimesh cannot "
                            "fill): a soft body needs a closed surface with an inside")
        notes.append("the mesh was not closed: trimesh filled its holes")
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
        notes.append("inconsistent triangle winding was fixed")
    if mesh.volume < 0:
        mesh.invert()
        notes.append("the mesh was inside out: its triangles were turned outward")
    if not mesh.volume > 0:
        raise UserError(f"{str(path)!r}: the mesh encloses no volume")
    return mesh, notes


def lattice_shape(extent, n: int) -> tuple[tuple[int, int, int], float]:
    """(points per axis, spacing h [m]) of the lattice over a box of side lengths ``extent`` [m]:
    n points along the longest side, h = longest / (n - 1), as many points as fit along the others."""
    extent = np.asarray(extent, dtype=np.float64)
    h = float(extent.max()) / (n - 1)
    shape = tuple(int(np.floor(e / h + 1e-9)) + 1 for e in extent)
    return shape, h


def _springs(exists: np.ndarray, grid: np.ndarray, h: float):
    """(pairs, kind, rest) of the stencil between existing lattice points, in ``lattice`` order:
    kinds, then offsets, then start point in C order."""
    dims = np.array(exists.shape)
    pairs, kinds, rests = [], [], []
    for kind, off in SPRING_OFFSETS:
        o = np.array(off)
        lo = np.maximum(-o, 0)
        hi = dims - np.maximum(o, 0)
        if np.any(hi <= lo):
            continue
        a_sl = tuple(slice(lo[d], hi[d]) for d in range(3))
        b_sl = tuple(slice(lo[d] + o[d], hi[d] + o[d]) for d in range(3))
        both = exists[a_sl] & exists[b_sl]
        a = grid[a_sl][both]  # boolean indexing walks C order: start points in lattice order
        b = grid[b_sl][both]
        pairs.append(np.stack([a, b], axis=1))
        kinds.append(np.full(len(a), kind, np.int8))
        rests.append(np.full(len(a), h * float(np.sqrt(o @ o))))
    if not pairs:
        return np.zeros((0, 2), np.int32), np.zeros(0, np.int8), np.zeros(0)
    return np.concatenate(pairs).astype(np.int32), np.concatenate(kinds), np.concatenate(rests)


def _number(exists: np.ndarray) -> np.ndarray:
    """Particle index of each existing lattice point in C order, -1 elsewhere."""
    grid = np.full(exists.shape, -1, np.int64)
    grid[exists] = np.arange(int(exists.sum()))
    return grid


def _embedding(vertices, points, grid, origin, h):
    """Per mesh vertex: particle indices and weights [nv, 8] (module docstring), [nv, NEAREST]
    when some vertex lies in a cell that misses corners."""
    from scipy.spatial import cKDTree

    dims = np.array(grid.shape)
    rel = (vertices - origin) / h
    cell = np.clip(np.floor(rel).astype(np.int64), 0, np.maximum(dims - 2, 0))
    f = rel - cell  # may leave [0, 1] only on a degenerate (one point thick) axis
    index = np.empty((len(vertices), 8), np.int64)
    weight = np.empty((len(vertices), 8))
    for c, (di, dj, dk) in enumerate(np.ndindex(2, 2, 2)):
        ci = np.minimum(cell + [di, dj, dk], dims - 1)
        index[:, c] = grid[ci[:, 0], ci[:, 1], ci[:, 2]]
        weight[:, c] = ((f[:, 0] if di else 1 - f[:, 0]) * (f[:, 1] if dj else 1 - f[:, 1])
                        * (f[:, 2] if dk else 1 - f[:, 2]))
    broken = (index < 0).any(axis=1) | np.any(dims < 2)
    if broken.any():
        k = min(NEAREST, len(points))
        v = vertices[broken]
        # One particle set per boundary cell: the k particles nearest its centre c. Minimum-norm
        # affine weights: sum w_i x_i = v and sum w_i = 1 (exact at rest whenever the k particles
        # are not coplanar), the smallest such w, so no particle dominates needlessly:
        # w = M [(v - c) / h; 1] with M = A^T (A A^T)^-1 and A = [(x_i - c) / h; 1] (4 x k), one
        # 4 x 4 inverse per cell. The tiny ridge keeps a coplanar set (a one-layer patch)
        # solvable, as a least-squares fit.
        flat, which = np.unique(np.ravel_multi_index(cell[broken].T, dims), return_inverse=True)
        cells = np.stack(np.unravel_index(flat, dims), axis=1)
        centre = origin + (cells + 0.5) * h
        _, near = cKDTree(points).query(centre, k=k)
        near = near.reshape(-1, k)
        a = np.concatenate([(points[near] - centre[:, None]).transpose(0, 2, 1) / h, np.ones((len(cells), 1, k))],
                           axis=1)
        m = a.transpose(0, 2, 1) @ np.linalg.inv(a @ a.transpose(0, 2, 1) + 1e-12 * np.eye(4))  # [cells, k, 4]
        b_ = np.concatenate([(v - centre[which]) / h, np.ones((len(v), 1))], axis=1)
        w = np.einsum("vkj,vj->vk", m[which], b_)
        near = near[which]
        if k > 8:  # widen every row: one gather width for the device kernel
            index = np.concatenate([index, np.zeros((len(index), k - 8), np.int64)], axis=1)
            weight = np.concatenate([weight, np.zeros((len(weight), k - 8))], axis=1)
        index[broken] = 0
        weight[broken] = 0.0
        index[broken, :k] = near
        weight[broken, :k] = w
    return index.astype(np.int32), weight


def _fill(mesh, notes: list, n: int, size: float | None, scale: float | None, path: Path) -> MeshLattice:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from trimesh.ray.ray_util import contains_points

    lo, hi = mesh.bounds
    centre = 0.5 * (lo + hi)
    factor = scale if scale is not None else size / float((hi - lo).max())
    vertices = (np.asarray(mesh.vertices, dtype=np.float64) - centre) * factor  # body frame [m]
    triangles = np.asarray(mesh.faces, dtype=np.int64)
    extent = (hi - lo) * factor
    shape, h = lattice_shape(extent, n)
    axes = [(np.arange(m) - 0.5 * (m - 1)) * h for m in shape]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    # The test runs in mesh units, where trimesh's tolerances were set up.
    test = pts - _INWARD * h * np.sign(pts)
    inside = contains_points(mesh.ray, test / factor + centre, check_direction=_RAY_DIRECTION)
    exists = inside.reshape(shape)
    # Drop points without springs and small pieces: components of the full stencil graph.
    grid = _number(exists)
    pairs, _, _ = _springs(exists, grid, h)
    count = int(exists.sum())
    dropped = 0
    if count:
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(count, count))
        _, label = connected_components(graph, directed=False)
        sizes = np.bincount(label)
        keep = sizes[label] >= MIN_COMPONENT
        dropped = int(count - keep.sum())
        if dropped:
            flat = exists.ravel().copy()
            flat[np.flatnonzero(flat)[~keep]] = False
            exists = flat.reshape(shape)
            grid = _number(exists)
    if not exists.any():
        raise UserError(f"{str(path)!r}: at n = {n} (spacing {h:.3g} m) no spring-connected body of "
                        f"{MIN_COMPONENT} or more particles fits inside the mesh; it is too thin for the lattice: "
                        f"raise n")
    pairs, kind, rest = _springs(exists, grid, h)
    points = pts[exists.ravel()]
    flat = np.ptp(points, axis=0) < 0.5 * h
    if flat.any():  # one layer of points: no stiffness across it, nothing to hold a shape
        raise UserError(f"{str(path)!r}: at n = {n} (spacing {h:.3g} m) the lattice inside the mesh is a single "
                        f"layer along {'/'.join('xyz'[a] for a in np.flatnonzero(flat))}: the mesh is too thin for "
                        "the lattice: raise n")
    notes = list(notes)
    if dropped:
        notes.append(f"{dropped} lattice point(s) without enough springs were dropped")
    origin = np.array([a[0] for a in axes])
    index, weight = _embedding(vertices, points, grid, origin, h)
    return MeshLattice(path, h, grid.astype(np.int32), points, pairs, kind, rest, vertices, triangles, index, weight,
                       float(mesh.volume) * factor**3, dropped, notes)


def particle_surface(m: MeshLattice) -> np.ndarray:
    """The input surface in particle terms, [t, 3] local particle indices: each mesh vertex
    replaced by the particle it follows with the largest weight, triangles that collapse dropped.
    A coarse, outward-wound stand-in for the drawn surface where particles are needed (picking)."""
    main = m.embed_index[np.arange(len(m.embed_index)), np.argmax(m.embed_weight, axis=1)]
    tri = main[m.triangles].astype(np.int64)
    keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
    return tri[keep]


@functools.lru_cache(maxsize=8)
def _cached(path: str, stamp: tuple, n: int, size: float | None, scale: float | None) -> MeshLattice:
    mesh, notes = load_mesh(Path(path))
    return _fill(mesh, notes, n, size, scale, Path(path))


def mesh_lattice(path, n: int, size: float | None = None, scale: float | None = None, key: str = "mesh") -> MeshLattice:
    """The lattice body of the closed mesh in ``path`` (module docstring): ``n`` points along the
    longest side, which is ``size`` metres long, or the mesh scaled by ``scale`` metres per unit.

    Cached per (file, modification time, n, size, scale): treat the result as read-only.
    Raises ``UserError`` naming ``key`` for bad input.
    """
    if (size is None) == (scale is None):
        raise ValueError("give exactly one of size and scale")
    path = Path(path)
    try:
        st = path.stat()
        stamp = (st.st_mtime_ns, st.st_size)
    except OSError:
        stamp = None  # load_mesh says what is wrong
    try:
        return _cached(str(path.resolve() if stamp else path), stamp, int(n), size, scale)
    except UserError as e:
        raise UserError(f"{key} = {e}") from None


def spec_lattice(spec, key: str = "mesh") -> MeshLattice:
    """``mesh_lattice`` of a mesh ``bodies.BodySpec`` (its ``mesh``, ``n`` and ``scale`` or ``size``)."""
    if spec.scale is not None:
        return mesh_lattice(spec.mesh, spec.n, scale=spec.scale, key=key)
    return mesh_lattice(spec.mesh, spec.n, size=spec.size, key=key)
