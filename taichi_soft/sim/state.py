"""A model's changing state: ``State`` holds the positions and velocities of all particles
(``Model.state()`` makes one at the model's initial state)."""

import numpy as np
import taichi as ti

from .allocation import numpy_real, page_aligned_vectors


@ti.data_oriented
class State:
    """Positions x [m] and velocities v [m/s] of all particles, shape [n_particles] vec3."""

    def __init__(self, n_particles: int):
        self.n_particles = n_particles
        self.real = numpy_real()  # the numpy dtype of x and v
        self.x, self.v = page_aligned_vectors(n_particles, 2)

    def set(self, x: np.ndarray, v: np.ndarray):
        """Copy positions [m] and velocities [m/s], arrays [n_particles, 3], into the state.

        One kernel (no host copy when the arrays are already in the run's precision).
        """
        arrays = []
        for name, a in (("x", x), ("v", v)):
            a = np.ascontiguousarray(a, dtype=self.real)
            if a.shape != (self.n_particles, 3):
                raise ValueError(f"State.set: {name} has shape {a.shape}, expected ({self.n_particles}, 3)")
            arrays.append(a)
        self._set(*arrays)

    @ti.kernel
    def _set(self, x: ti.types.ndarray(ndim=2), v: ti.types.ndarray(ndim=2)):
        for i in range(self.n_particles):
            self.x[i] = ti.cast(ti.Vector([x[i, 0], x[i, 1], x[i, 2]]), float)
            self.v[i] = ti.cast(ti.Vector([v[i, 0], v[i, 1], v[i, 2]]), float)

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of (x, v) as numpy arrays [n_particles, 3] in the run's precision.

        One kernel per state (``to_numpy`` would compile one per field, about 20 ms each).
        """
        x = np.empty((self.n_particles, 3), dtype=self.real)
        v = np.empty_like(x)
        self._get(x, v)
        return x, v

    @ti.kernel
    def _get(self, x: ti.types.ndarray(ndim=2), v: ti.types.ndarray(ndim=2)):
        for i in range(self.n_particles):
            for c in ti.static(range(3)):
                x[i, c] = self.x[i][c]
                v[i, c] = self.v[i][c]

    def copy_from(self, other: "State"):
        self.x.copy_from(other.x)
        self.v.copy_from(other.v)
