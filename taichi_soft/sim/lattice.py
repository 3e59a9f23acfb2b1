"""Rest-shape geometry of a soft cube: particle lattice, spring layout and surface triangles.

Index of lattice point (i, j, k) is ``(i * n + j) * n + k`` (i along x, j along y, k along z).
The springs follow from index arithmetic alone, so they are written straight into the model's
device fields by a kernel (``fill_springs``): no host copy of the per-spring arrays is ever made,
which is what lets a million-particle body fit in about a gigabyte (docs/benchmarks.md, memory).

Spring order (what every array indexed by spring id follows): kinds in the order STRETCH, SHEAR,
BEND; within a kind, the offsets in the order of ``_OFFSETS``; within an offset, the start point
p in lattice (C) order over the points for which p + offset is inside the lattice.
"""

import math

import numpy as np
import taichi as ti

STRETCH, SHEAR, BEND = 0, 1, 2
SPRING_KINDS = ("stretch", "shear", "bend")

# Lattice offsets of each spring kind. Only one of each +/- pair is listed so every spring is
# built once: 3 stretch (axis neighbours), 6 face-diagonal + 4 body-diagonal shear, 3 bend
# (axis neighbours two apart).
_OFFSETS = {
    STRETCH: [(1, 0, 0), (0, 1, 0), (0, 0, 1)],
    SHEAR: [(1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1), (0, 1, 1), (0, 1, -1),
            (1, 1, 1), (1, 1, -1), (1, -1, 1), (1, -1, -1)],
    BEND: [(2, 0, 0), (0, 2, 0), (0, 0, 2)],
}
# (kind, offset) in spring order.
SPRING_OFFSETS = tuple((kind, off) for kind, offsets in _OFFSETS.items() for off in offsets)


def offset_count(n: int, off) -> int:
    """Springs of one offset in an n^3 lattice: start points p with p + off inside it."""
    return math.prod(max(n - abs(o), 0) for o in off)


def spring_counts(n: int) -> tuple[int, int, int]:
    """(stretch, shear, bend) spring counts of an n^3 lattice, without building anything.

    Closed forms: 3 n^2 (n-1); 6 n (n-1)^2 + 4 (n-1)^3; 3 n^2 (n-2). For n = 10: 2700, 7776, 2400.
    """
    counts = [0, 0, 0]
    for kind, off in SPRING_OFFSETS:
        counts[kind] += offset_count(n, off)
    return tuple(counts)


def spring_count(n: int) -> int:
    """Total springs of an n^3 lattice (about 16 per particle for large n)."""
    return sum(spring_counts(n))


def spring_table(n: int) -> dict:
    """Per offset q (in spring order): first spring id ``base[q]`` (``base[-1]`` = total), lattice
    offset ``off[q]`` and ``kind[q]``, as small int32 arrays for ``fill_springs``."""
    counts = [offset_count(n, off) for _, off in SPRING_OFFSETS]
    return {"base": np.concatenate([[0], np.cumsum(counts)]).astype(np.int32),
            "off": np.array([off for _, off in SPRING_OFFSETS], dtype=np.int32),
            "kind": np.array([kind for kind, _ in SPRING_OFFSETS], dtype=np.int32)}


def fill_springs(ends, rest, group, n: int, p0: int, s0: int, g0: int, h: float):
    """Write one body's springs into the fields ``ends`` (ivec2), ``rest`` [m] and ``group``.

    The body is an n^3 lattice of spacing ``h`` [m] whose particles start at index ``p0``; its
    springs take ids s0, s0 + 1, ... in spring order and groups ``g0 + kind``. Rest lengths are
    h |offset|: a rotation or start deformation of the body does not change them.
    """
    t = spring_table(n)
    _fill_springs(ends, rest, group, t["base"], t["off"], t["kind"], n, p0, s0, g0, h)


@ti.kernel
def _fill_springs(ends: ti.template(), rest: ti.template(), group: ti.template(), base: ti.types.ndarray(ndim=1),
                  off: ti.types.ndarray(ndim=2), kind: ti.types.ndarray(ndim=1), n: ti.i32, p0: ti.i32, s0: ti.i32,
                  g0: ti.i32, h: float):
    # One loop over springs (not an unrolled loop over offsets: that takes seconds to compile).
    for s in range(base[base.shape[0] - 1]):
        q = 0
        while s >= base[q + 1]:
            q += 1
        o = ti.Vector([off[q, 0], off[q, 1], off[q, 2]])
        box = n - ti.abs(o)  # start points of offset q: a box of box[0] x box[1] x box[2]
        r = s - base[q]  # rank of the start point in that box, C order
        c = ti.Vector([r // (box[1] * box[2]), (r // box[2]) % box[1], r % box[2]]) + ti.max(-o, 0)
        a = (c[0] * n + c[1]) * n + c[2]
        ends[s0 + s] = ti.Vector([p0 + a, p0 + a + (o[0] * n + o[1]) * n + o[2]])
        rest[s0 + s] = h * ti.sqrt(ti.cast(o.dot(o), float))
        group[s0 + s] = g0 + kind[q]


def lattice_pairs_among(n: int, p0: int, near) -> np.ndarray:
    """Spring ends [k, 2] int32 (global indices, particles from ``p0``) of an n^3 lattice's springs
    whose two ends are both ``near`` (a bool mask over the body's n^3 points), in spring order,
    without the whole spring list: a bool array of n^3 per offset at a time."""
    near = np.asarray(near, bool).reshape(n, n, n)
    idx = lattice_index(n)
    out = []
    for _, off in SPRING_OFFSETS:
        lo = [max(-o, 0) for o in off]  # start points: lo <= p < n - max(o, 0)
        hi = [n - max(o, 0) for o in off]
        if min(h - l for l, h in zip(lo, hi)) <= 0:
            continue
        a = tuple(slice(l, h) for l, h in zip(lo, hi))
        b = tuple(slice(l + o, h + o) for l, h, o in zip(lo, hi, off))
        ok = near[a] & near[b]
        out.append(np.stack([idx[a][ok], idx[b][ok]], axis=1))
    return (np.concatenate(out) + p0).astype(np.int32) if out else np.zeros((0, 2), np.int32)


def envelope_size(n: int) -> int:
    """Values of the skyline (envelope) Cholesky factor of an n^3 lattice's spring graph in
    lattice order: the sum over rows of (row index - first neighbour's index + 1).

    Computed per (j, k) plane for the three kinds of layer i = 0, 1, >= 2 (a layer's rows only
    differ by which neighbours two layers back exist), so it costs O(n^2) even for n = 200.
    """
    j, k = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    total = 0
    for i, layers in ((0, 1), (1, 1 if n > 1 else 0), (2, max(n - 2, 0))):
        if layers == 0:
            continue
        width = np.zeros((n, n), dtype=np.int64)  # row index - first column, per (j, k)
        for _, off in SPRING_OFFSETS:  # every offset steps to a higher index: p - off is below p
            if i - off[0] < 0:
                continue
            ok = (j - off[1] >= 0) & (j - off[1] < n) & (k - off[2] >= 0) & (k - off[2] < n)
            np.maximum(width, np.where(ok, (off[0] * n + off[1]) * n + off[2], 0), out=width)
        total += layers * int((width + 1).sum())
    return total


def lattice_points(n: int, size: float) -> np.ndarray:
    """Rest positions [m] of an n^3 lattice of edge ``size`` centred on the origin, shape [n^3, 3].

    Filled in place (no meshgrid copies): 24 bytes per particle and nothing else.
    """
    axis = np.linspace(-0.5 * size, 0.5 * size, n)
    pts = np.empty((n, n, n, 3))
    pts[..., 0] = axis[:, None, None]
    pts[..., 1] = axis[None, :, None]
    pts[..., 2] = axis[None, None, :]
    return pts.reshape(n ** 3, 3)


def lattice_index(n: int) -> np.ndarray:
    """Particle index of every lattice point, shape [n, n, n]."""
    return np.arange(n ** 3).reshape(n, n, n)


def surface_triangles(n: int) -> np.ndarray:
    """Outer surface of the lattice as triangles with outward (counter-clockwise) winding.

    Shape [12 (n-1)^2, 3] particle indices, local to the cube.
    """
    idx = lattice_index(n)
    tris = []
    # Each face: fix one axis at 0 or n-1, walk the other two. (u, v) ordered so that
    # u x v points along the face's outward normal on the max side.
    for axis in range(3):
        u_axis, v_axis = [(1, 2), (2, 0), (0, 1)][axis]
        for side, outward in ((0, False), (n - 1, True)):
            face = np.take(idx, side, axis=axis)  # 2-D array over the two remaining axes
            # np.take drops `axis`; remaining axes keep their order: map (u, v) into it.
            rem = [a for a in range(3) if a != axis]
            face = face if rem.index(u_axis) == 0 else face.T
            q00, q10 = face[:-1, :-1].ravel(), face[1:, :-1].ravel()
            q01, q11 = face[:-1, 1:].ravel(), face[1:, 1:].ravel()
            t1 = np.stack([q00, q10, q11], axis=1)
            t2 = np.stack([q00, q11, q01], axis=1)
            t = np.concatenate([t1, t2])
            if not outward:
                t = t[:, ::-1]
            tris.append(t)
    return np.concatenate(tris).astype(np.int64)


def rotation_matrix(axis, degrees: float) -> np.ndarray:
    """Rotation by ``degrees`` about ``axis`` (need not be unit length), Rodrigues' formula."""
    axis = np.asarray(axis, dtype=np.float64)
    norm = np.linalg.norm(axis)
    if degrees == 0.0 or norm == 0.0:
        return np.eye(3)
    k = axis / norm
    theta = np.radians(degrees)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx
