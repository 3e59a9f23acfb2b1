"""Padded spring rows: each particle's springs in a fixed-width row, for the gathered force pass.

Particle i's springs sit in slots ``i * width ... i * width + width - 1`` (``width`` = the most
springs any particle has; 32 inside a lattice of n >= 5): the other end, the rest length [m], the
group (``model.spring_group``) and (k [N/m], kd [N s/m]) copied from the group. Unused slots are
padding: a spring from the particle to itself of rest length 0, whose force is exactly zero
(``forces.spring_force`` of d = 0 is 0, with no NaN). A loop over a row then has a constant trip
count, which is what lets LLVM vectorise it whole (docs/benchmarks/README.md, "Speed"): a CSR
row of varying length left every particle with fewer than 32 springs (the lattice's surface)
entirely scalar.

Rows are built on the device from ``model.spring_ends`` (no host copy of the springs, no CSR
adjacency): a serial pass over the springs, so each row lists its springs by increasing id and
every build, every run, sums a particle's forces in the same order (bit-identical repeats).
Memory per particle: ``width`` x (2 ints + 3 reals), or 2 ints + 1 real without the (k, kd)
copies (``copies=False``: the force pass reads them through the group, ``forces.rows_look_up_groups``).
"""

import numpy as np
import taichi as ti


def lattice_width(n: int) -> int:
    """Row width of an n^3 lattice body: the springs of its most central particle (32 for n >= 5)."""
    from .lattice import SPRING_OFFSETS  # imports Taichi: callers before start-up import lazily

    c = (n - 1) // 2
    count = 0
    for _, off in SPRING_OFFSETS:
        for sign in (1, -1):
            count += all(0 <= c + sign * o < n for o in off)
    return count


@ti.data_oriented
class SpringRows:
    """The padded rows of one model (see the module docstring). ``kkd`` (with ``copies``) is filled
    from the groups by ``ForceEvaluator.refresh``, in the step kernels, whenever the groups change."""

    def __init__(self, model, copies: bool = True):
        self.model = model
        n = model.n_particles
        degree = ti.ndarray(ti.i32, max(n, 1))  # springs per particle, then the fill cursor
        self.width = max(self._count(degree), 1)
        slots = max(n, 1) * self.width
        self.other = ti.field(ti.i32, slots)
        self.rest = ti.field(float, slots)
        self.group = ti.field(ti.i32, slots)
        self.copies = copies  # a compile-time constant of the force pass
        self.kkd = ti.Vector.field(2, float, slots) if copies else None
        self._fill(degree)

    @ti.kernel
    def _count(self, degree: ti.types.ndarray(ndim=1)) -> ti.i32:
        m = self.model
        for i in range(m.n_particles):
            degree[i] = 0
        for s in range(m.n_springs):
            ti.atomic_add(degree[m.spring_ends[s][0]], 1)
            ti.atomic_add(degree[m.spring_ends[s][1]], 1)
        width = 0
        for i in range(m.n_particles):
            ti.atomic_max(width, degree[i])
        return width

    @ti.kernel
    def _fill(self, cursor: ti.types.ndarray(ndim=1)):
        m = self.model
        w = ti.static(self.width)
        for i in range(m.n_particles):
            cursor[i] = 0
            for k in range(w):  # padding first; the springs overwrite their slots below
                self.other[i * w + k] = i
                self.rest[i * w + k] = 0.0
                self.group[i * w + k] = 0
        ti.loop_config(serialize=True)  # by increasing spring id: the same rows every time
        for s in range(m.n_springs):
            for end in ti.static(range(2)):
                p = m.spring_ends[s][end]
                slot = p * w + cursor[p]
                cursor[p] += 1
                self.other[slot] = m.spring_ends[s][1 - end]
                self.rest[slot] = m.spring_rest[s]
                self.group[slot] = m.spring_group[s]

    def numpy_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """(other [n, width] int32, rest [n, width]) as host arrays (tests and tools)."""
        n = self.model.n_particles
        return (self.other.to_numpy()[: n * self.width].reshape(n, self.width),
                self.rest.to_numpy()[: n * self.width].reshape(n, self.width))
