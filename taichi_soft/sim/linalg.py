"""Linear algebra on Taichi fields for the implicit integrators.

* ``PCG``: matrix-free preconditioned conjugate gradients on vec3 fields, buffers allocated once,
  scalars and the convergence flag kept on the device (in the spirit of Genesis' ``fem_solver``).
* ``SkylineCholesky``: a profile (skyline) Cholesky factorisation A = L L^T of a sparse symmetric
  positive definite n x n matrix, applied to vec3 right-hand sides (a matrix of the form A (x) I3,
  as the fast mass-spring system matrix is). Factorised and solved inside kernels, so a whole
  step of the local/global solver stays in one launch.

Both are written as ``ti.func`` pieces made of top-level loops: inside a kernel's serialized
outer loop they run serially (one launch for many steps, best on a CPU for small bodies); called
at a kernel's top level the PCG pieces run in parallel (one launch per CG iteration, for GPUs or
large bodies). The triangular solves are serial by nature and force serial execution.
"""

import numpy as np
import taichi as ti

from .allocation import allocate
from .footprint import VEC, per_particle


@ti.data_oriented
class PCG:
    """Preconditioned conjugate gradients for A x = b, x and b vec3 fields of ``n`` entries.

    The operator ``op`` passed to the functions is any data-oriented object with
      ``apply(src, dst)``        dst = A src, A symmetric positive semi-definite;
      ``precondition(src, dst)`` dst = P^{-1} src, P^{-1} symmetric positive semi-definite;
      ``prepare_preconditioner()`` called once at the start of each solve, before the first
                                 ``precondition`` (A and P do not change within a solve);
    all three made of top-level loops. A may be singular on directions P^{-1} removes (constraint
    filtering as in Baraff & Witkin 1998, Sec. 5.3: both maps return zero on filtered components
    and the iteration stays in the unfiltered subspace).

    Stopping rule: (r . P^{-1} r) <= rel_tol^2 (r0 . P^{-1} r0), i.e. the residual in the
    preconditioner's norm falls by ``rel_tol``, or the iteration limit.
    """

    BUFFERS = {
        "r": per_particle("residual b - A x", VEC),
        "z": per_particle("preconditioned residual", VEC),
        "p": per_particle("search direction", VEC),
        "q": per_particle("A p", VEC),
    }

    def __init__(self, n: int):
        self.n = n
        allocate(self, self.BUFFERS, n, 0)
        self.rz = ti.field(float, ())
        self.rz0 = ti.field(float, ())
        self.pq = ti.field(float, ())
        self.rel_tol = ti.field(float, ())
        self.iters = ti.field(ti.i32, ())  # iterations of the last solve
        self.done = ti.field(ti.i32, ())  # 1 once converged (or a zero/negative curvature stop)

    @ti.func
    def init(self, op: ti.template(), b: ti.template(), x: ti.template()):
        """Start a solve from x = 0."""
        for i in range(self.n):
            x[i] = ti.Vector.zero(float, 3)
            self.r[i] = b[i]
        op.prepare_preconditioner()
        op.precondition(self.r, self.z)
        self.rz[None] = 0.0
        for i in range(self.n):
            self.p[i] = self.z[i]
            self.rz[None] += self.r[i].dot(self.z[i])
        self.rz0[None] = self.rz[None]
        self.iters[None] = 0
        self.done[None] = ti.cast(self.rz[None] <= 0.0, ti.i32)

    @ti.func
    def iterate(self, op: ti.template(), x: ti.template()):
        """One CG iteration (a no-op once ``done``)."""
        op.apply(self.p, self.q)
        self.pq[None] = 0.0
        for i in range(self.n):
            self.pq[None] += self.p[i].dot(self.q[i])
        alpha = ti.cast(0.0, float)
        if self.done[None] == 0:
            if self.pq[None] > 0:
                alpha = self.rz[None] / self.pq[None]
            else:
                self.done[None] = 1  # no curvature left along p: nothing more to gain
        for i in range(self.n):
            x[i] += alpha * self.p[i]
            self.r[i] -= alpha * self.q[i]
        op.precondition(self.r, self.z)
        rz_old = self.rz[None]
        self.rz[None] = 0.0
        for i in range(self.n):
            self.rz[None] += self.r[i].dot(self.z[i])
        beta = ti.cast(0.0, float)
        if self.done[None] == 0:
            self.iters[None] += 1
            beta = self.rz[None] / rz_old
            if self.rz[None] <= self.rel_tol[None] ** 2 * self.rz0[None]:
                self.done[None] = 1
        for i in range(self.n):
            self.p[i] = self.z[i] + beta * self.p[i]

    @ti.func
    def solve(self, op: ti.template(), b: ti.template(), x: ti.template(), max_iters):
        """Whole solve; only for serial code (its iteration loop must not run in parallel)."""
        self.init(op, b, x)
        for _ in range(max_iters):
            if self.done[None] != 0:
                break
            self.iterate(op, x)

    # Python-driven variant for parallel execution: one launch per iteration, the flag is read
    # back every ``check_every`` iterations (each read is a device sync).
    @ti.kernel
    def _k_init(self, op: ti.template(), b: ti.template(), x: ti.template()):
        self.init(op, b, x)

    @ti.kernel
    def _k_iterate(self, op: ti.template(), x: ti.template()):
        self.iterate(op, x)

    def solve_parallel(self, op, b, x, max_iters: int, check_every: int = 4) -> int:
        """Solve from Python scope; returns the iterations used."""
        self._k_init(op, b, x)
        for k in range(max_iters):
            if k % check_every == 0 and self.done[None]:
                break
            self._k_iterate(op, x)
        return int(self.iters[None])


@ti.data_oriented
class SkylineCholesky:
    """Profile Cholesky A = L L^T of a sparse SPD n x n matrix, solving A X = B for vec3 columns.

    Row i of L is stored densely from its first structural non-zero ``start[i]`` (the smallest
    column coupled to i) to the diagonal; Cholesky creates no fill outside this envelope. For the
    lattice ordering of an n^3 cube the envelope is at most 2 n^2 + 1 wide (bend springs two
    layers apart), so storage is about N (2 n^2) values and a solve costs 2 N (2 n^2) multiply-adds
    per coordinate; factorising costs about N (2 n^2)^2 / 2.

    Usage: ``clear()`` the values, add entries with ``add(i, j, value)`` (lower triangle, i >= j;
    a ti.func), then ``factor()`` (kernel) and ``solve(b, x)`` (ti.func, serial).
    """

    @staticmethod
    def envelope_starts(n: int, pairs: np.ndarray) -> np.ndarray:
        """First structurally non-zero column of each row of the lower triangle."""
        start = np.arange(n)
        if len(pairs):
            lo = np.minimum(pairs[:, 0], pairs[:, 1])
            hi = np.maximum(pairs[:, 0], pairs[:, 1])
            np.minimum.at(start, hi, lo)
        return start

    @classmethod
    def envelope_size(cls, n: int, pairs: np.ndarray) -> int:
        """Values the factor stores (its envelope), before allocating anything."""
        return int(np.sum(np.arange(n) - cls.envelope_starts(n, pairs) + 1))

    def __init__(self, n: int, pairs: np.ndarray):
        """``pairs`` [m, 2]: the structurally non-zero off-diagonal entries (either order)."""
        self.n = n
        start = self.envelope_starts(n, pairs)
        lengths = np.arange(n) - start + 1
        offset = np.concatenate([[0], np.cumsum(lengths)])
        self.nnz = int(offset[-1])
        self.bandwidth = int((np.arange(n) - start).max(initial=0))
        self.start = ti.field(ti.i32, n)
        self.offset = ti.field(ti.i32, n + 1)
        self.val = ti.field(float, max(self.nnz, 1))
        self.start.from_numpy(start.astype(np.int32))
        self.offset.from_numpy(offset.astype(np.int32))
        self.ok = ti.field(ti.i32, ())  # 1 if the last factorisation found A positive definite
        self.tmp = ti.Vector.field(3, float, n)

    @ti.func
    def index(self, i, j):
        """Position of entry (i, j), i >= j >= start[i], in ``val``."""
        return self.offset[i] + j - self.start[i]

    @ti.func
    def clear(self):
        for k in range(self.nnz):
            self.val[k] = 0.0

    @ti.func
    def add(self, i, j, value):
        """A[i, j] += value for i >= j (the lower triangle; atomic, safe in parallel loops)."""
        self.val[self.index(i, j)] += value

    @ti.kernel
    def factor(self):
        """Overwrite the stored lower triangle of A with L (left-looking, row by row)."""
        self.ok[None] = 1
        ti.loop_config(serialize=True)
        for i in range(self.n):
            si = self.start[i]
            for j in range(si, i + 1):
                k0 = ti.max(si, self.start[j])
                s = self.val[self.index(i, j)]
                for k in range(k0, j):
                    s -= self.val[self.index(i, k)] * self.val[self.index(j, k)]
                if j < i:
                    self.val[self.index(i, j)] = s / self.val[self.index(j, j)]
                else:
                    if not (s > 0):
                        self.ok[None] = 0
                        s = 1.0  # keep going so the caller can report instead of dividing by 0
                    self.val[self.index(i, i)] = ti.sqrt(s)

    @ti.func
    def solve(self, b: ti.template(), x: ti.template()):
        """x = A^{-1} b (b and x vec3 fields, may be the same field). Serial."""
        # Forward substitution L t = b.
        ti.loop_config(serialize=True)
        for i in range(self.n):
            s = b[i]
            for k in range(self.start[i], i):
                s -= self.val[self.index(i, k)] * self.tmp[k]
            self.tmp[i] = s / self.val[self.index(i, i)]
        # Backward substitution L^T x = t, column-oriented so L is read by rows again.
        ti.loop_config(serialize=True)
        for r in range(self.n):
            i = self.n - 1 - r
            xi = self.tmp[i] / self.val[self.index(i, i)]
            x[i] = xi
            for k in range(self.start[i], i):
                self.tmp[k] -= self.val[self.index(i, k)] * xi

    @ti.kernel
    def solve_kernel(self, b: ti.template(), x: ti.template()):
        self.solve(b, x)
