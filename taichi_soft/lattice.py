"""Rest-shape geometry of a soft cube: particle lattice, spring pairs and surface triangles.

Pure numpy, no Taichi: the builder turns these arrays into device fields.
Index of lattice point (i, j, k) is ``(i * n + j) * n + k`` (i along x, j along y, k along z).
"""
from __future__ import annotations

import numpy as np

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


def lattice_index(n: int) -> np.ndarray:
    """Particle index of every lattice point, shape [n, n, n]."""
    return np.arange(n ** 3).reshape(n, n, n)


def lattice_points(n: int, size: float) -> np.ndarray:
    """Rest positions [m] of an n^3 lattice of edge ``size`` centred on the origin, shape [n^3, 3]."""
    axis = np.linspace(-0.5 * size, 0.5 * size, n)
    gx, gy, gz = np.meshgrid(axis, axis, axis, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)


def lattice_springs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Spring end points and kinds of an n^3 lattice.

    Returns ``(pairs, kinds)``: pairs [n_springs, 2] int64 particle indices, kinds [n_springs]
    in {STRETCH, SHEAR, BEND}. For n = 10: 2700 stretch, 7776 shear and 2400 bend springs.
    """
    idx = lattice_index(n)
    pairs, kinds = [], []
    for kind, offsets in _OFFSETS.items():
        for off in offsets:
            # Slice the lattice so that both p and p + off are inside it.
            src = tuple(slice(max(0, -o), n - max(0, o)) for o in off)
            dst = tuple(slice(max(0, o), n - max(0, -o)) for o in off)
            a, b = idx[src].ravel(), idx[dst].ravel()
            pairs.append(np.stack([a, b], axis=1))
            kinds.append(np.full(a.size, kind))
    return np.concatenate(pairs).astype(np.int64), np.concatenate(kinds).astype(np.int64)


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
