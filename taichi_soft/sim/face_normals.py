"""Which faces of its body each particle lies on, in the body's rest frame: what makes body-body
contact flat along a face (``contact.bodies``).

A lattice point lies on a face for each of its six axis neighbours that is missing (out of the
cube, or outside a mesh body's lattice), with that direction as the face's outward normal: one face
for a point inside a face, two on an edge, three at a corner, none inside the body. At run time the
normals turn with the body's best-fit rotation (``contact.bodies.BodyContacts``), computed from the rest
positions returned here.
"""

import numpy as np

from .lattice import lattice_index, lattice_points

# The six outward directions, in the order of the bits of a face mask: +x, +y, +z, -x, -y, -z.
AXES = np.concatenate([np.eye(3, dtype=np.int64), -np.eye(3, dtype=np.int64)])


def _lattice_faces(grid: np.ndarray) -> np.ndarray:
    """Face masks [n_particles] (bit a: neighbour ``AXES[a]`` missing) of the lattice ``grid``
    (particle index per point, -1 empty)."""
    coords = np.argwhere(grid >= 0)
    index = grid[tuple(coords.T)]
    missing = np.zeros((len(coords), 6), dtype=bool)
    for a, step in enumerate(AXES):
        nb = coords + step
        inside = np.all((nb >= 0) & (nb < grid.shape), axis=1)
        has = np.zeros(len(coords), dtype=bool)
        has[inside] = grid[tuple(nb[inside].T)] >= 0
        missing[:, a] = ~has
    out = np.zeros(int(grid.max()) + 1, np.int32)
    out[index] = (missing * (1 << np.arange(6))).sum(axis=1)
    return out


def rest_frames(model) -> tuple[np.ndarray, np.ndarray]:
    """Each particle's rest position [m] relative to its body's mean rest position [n_particles, 3],
    and its face mask [n_particles] (``_lattice_faces``)."""
    rest = np.zeros((model.n_particles, 3))
    faces = np.zeros(model.n_particles, np.int32)
    for body in model.bodies:
        spec = body.spec
        if body.mesh is not None:
            pts, grid = body.mesh.points, body.mesh.grid
        else:
            pts, grid = lattice_points(spec.n, spec.size), lattice_index(spec.n)
        rest[body.particles] = pts - pts.mean(axis=0)
        faces[body.particles] = _lattice_faces(grid)
    return rest, faces
