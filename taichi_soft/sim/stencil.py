"""The stencil force pass: each particle finds its springs by lattice arithmetic, none stored.

Every cube body is an n^3 lattice (``lattice.py``): particle (a, b, c) of a body whose particles
start at p0 is p0 + (a n + b) n + c, and its springs go to (a, b, c) +- o for the 16 offsets o of
``lattice.SPRING_OFFSETS`` where that point is inside the lattice. Its rest length is h |o| (h the
body's spacing [m], whatever its rotation or start stretch) and its (k, kd) those of its body's
group of the offset's kind, read from ``model.group_k`` / ``group_kd`` every pass: a stiffness
changed at run time (the demo's sliders) acts on the next step, with nothing to refresh.

So the explicit methods keep no per-spring or per-slot array with this pass (``forces =
"stencil"``): the model never stores its springs (``Model.ensure_springs`` is not called) and the
memory estimate counts none (``memory.estimate``). A particle at least ``INTERIOR_MARGIN`` points
from every face of its lattice has all 32 neighbours: its loop reads them with no test. Near a face,
a point outside the lattice is replaced by the particle itself: d = 0 gives exactly zero force
(``forces.spring_force``, no NaN), so that loop too has a constant trip count and no branch, like
the gather's padded rows.

Directions run, per offset in spring order, -o then +o: the order of the gather's rows (rows.py:
a particle's springs by increasing id, and within one offset the spring that ends at it has the
lower id), so the two passes sum a particle's forces in the same order.

A mesh body is a clipped lattice (``meshbody``: its kept points numbered in C order, its springs
the stencil's between kept points, in the same order). Index arithmetic then gives the lattice
point, and a presence mask (``LatticeStencil.grid``: each point's particle or -1) the particle:
4 bytes per particle and per lattice point (the lattice padded by two empty points on every
side, so no neighbour needs a bound test), no per-spring array. A scene with a mesh body reads the
mask for every body (one compiled pass).
"""

import math

import numpy as np
import taichi as ti

from .forces import ForceEvaluator, spring_force
from .lattice import SPRING_OFFSETS
from .spring_codes import spring_group

# Force strategies whose pass reads the neighbours' state while a step writes the new one (the
# one-stage methods then ping-pong the state).
GATHERING = ("gather", "stencil")
# (kind, offset) of the 32 directions: per offset in spring order, -offset then +offset.
DIRECTIONS = tuple((kind, tuple(sign * o for o in off)) for kind, off in SPRING_OFFSETS for sign in (-1, 1))
N_DIRECTIONS = len(DIRECTIONS)
NAME = "stencil"
# The largest component of any lattice offset (the bend springs'): the interior fast path's margin.
INTERIOR_MARGIN = max(abs(c) for _, off in SPRING_OFFSETS for c in off)


def lattice_dims(info) -> tuple[int, int, int]:
    """Lattice points per axis of a body (``bodies.BodyInfo``): n^3 for a cube, its grid's for a mesh body."""
    return tuple(int(d) for d in info.mesh.grid.shape) if info.mesh is not None else (info.spec.n,) * 3


def lattice_points(dims_of_bodies) -> int:
    """Entries of the presence mask for bodies of the given points per axis: each body's lattice
    with INTERIOR_MARGIN empty points added on every side."""
    return sum(math.prod(d + 2 * INTERIOR_MARGIN for d in dims) for dims in dims_of_bodies)


def mask_ints(particles: int, points: int) -> int:
    """i32 entries of the presence mask (a scene with a mesh body; none when every body is a cube):
    each particle's lattice point and each lattice point's particle or -1."""
    return particles + points


@ti.data_oriented
class LatticeStencil:
    """A model's bodies as lattices, for index arithmetic: per body its first particle, points per
    axis, spacing [m]; per body and direction the lattice-point step and the rest length [m].
    O(bodies) fields when every body is a cube; with a mesh body (a clipped lattice) also the
    presence mask (``mask_ints``): each particle's point in its body's lattice and each point's
    particle, -1 where the mesh clipped it (every body then reads it, cubes included). The mask's
    lattices have INTERIOR_MARGIN empty points added on every side, so every particle's 32
    neighbours are entries of it and the pass reads them with no bound test."""

    def __init__(self, model):
        self.model = model
        self.masked = not model._lattice
        nb = max(len(model.bodies), 1)
        ends = np.array([info.particles.stop for info in model.bodies] or [0], np.int32)
        starts = np.array([info.particles.start for info in model.bodies] or [0], np.int32)
        dims = np.array([lattice_dims(info) for info in model.bodies] or [(1, 1, 1)], np.int32)
        steps = np.zeros((nb, N_DIRECTIONS), np.int32)
        for b, (_, ny, nz) in enumerate(dims + (2 * INTERIOR_MARGIN if self.masked else 0)):
            for q, (_, o) in enumerate(DIRECTIONS):
                steps[b, q] = (o[0] * int(ny) + o[1]) * int(nz) + o[2]
        self.n_bodies = len(model.bodies)
        self.body_end = ti.field(ti.i32, nb)
        self.body_start = ti.field(ti.i32, nb)
        self.body_dims = ti.Vector.field(3, ti.i32, nb)
        self.step = ti.field(ti.i32, nb * N_DIRECTIONS)
        self.rest = ti.field(float, nb * N_DIRECTIONS)
        self.offset = ti.Vector.field(3, ti.i32, N_DIRECTIONS)
        self.kind = ti.field(ti.i32, N_DIRECTIONS)
        self.point = self.grid = self.grid_start = None
        if self.masked:
            self._allocate_mask(model, dims)
        self.body_end.from_numpy(ends)
        self.body_start.from_numpy(starts)
        self.body_dims.from_numpy(dims)
        self.step.from_numpy(steps.ravel())
        self.offset.from_numpy(np.array([o for _, o in DIRECTIONS], np.int32))
        self.kind.from_numpy(np.array([k for k, _ in DIRECTIONS], np.int32))
        if self.masked:
            self._fill_mask(model)
        spacing = np.array([info.mesh.h if info.mesh is not None else info.spec.size / (info.spec.n - 1)
                            for info in model.bodies] or [1.0])
        self._fill_rest(spacing.astype(model.real))
        meshes = [b for b, info in enumerate(model.bodies) if info.mesh is not None]
        if meshes:
            # A mesh body's springs carry rest lengths rounded on the host (meshbody: float64, then
            # the run's precision): its directions take the same values, so the passes agree exactly.
            rest = self.rest.to_numpy().reshape(nb, N_DIRECTIONS)
            lengths = np.sqrt(np.array([np.dot(o, o) for _, o in DIRECTIONS], np.float64))
            for b in meshes:
                rest[b] = (model.bodies[b].mesh.h * lengths).astype(model.real)
            self.rest.from_numpy(rest.ravel())

    def _allocate_mask(self, model, dims):
        self.grid_start = ti.field(ti.i32, len(dims))
        self.point = ti.field(ti.i32, max(model.n_particles, 1))
        self.grid = ti.field(ti.i32, max(lattice_points(dims), 1))

    def _fill_mask(self, model):
        points, grid, first = [], [], []
        at, m = 0, INTERIOR_MARGIN
        for info in model.bodies:
            if info.mesh is None:
                local = np.arange(info.spec.n ** 3, dtype=np.int64).reshape((info.spec.n,) * 3)
            else:  # particles are numbered in the lattice's C order (meshbody)
                local = info.mesh.grid.astype(np.int64)
            padded = np.full(tuple(d + 2 * m for d in local.shape), -1, np.int64)
            padded[m:-m, m:-m, m:-m] = np.where(local >= 0, local + info.particles.start, -1)
            g = padded.ravel()
            points.append(np.flatnonzero(g >= 0))  # C order: the particles' order
            grid.append(g)
            first.append(at)
            at += len(g)
        self.grid_start.from_numpy(np.array(first, np.int32))
        self.point.from_numpy(np.concatenate(points).astype(np.int32))
        self.grid.from_numpy(np.concatenate(grid).astype(np.int32))

    @ti.kernel
    def _fill_rest(self, h: ti.types.ndarray(ndim=1)):
        # As lattice.fill_springs computes it (the same rounding): h |o|.
        for e in range(self.n_bodies * N_DIRECTIONS):
            o = self.offset[e % N_DIRECTIONS]
            self.rest[e] = ti.cast(h[e // N_DIRECTIONS], float) * ti.sqrt(ti.cast(o.dot(o), float))

    @ti.func
    def body_of(self, i):
        b = 0
        while i >= self.body_end[b]:
            b += 1
        return b

    @ti.func
    def locate(self, i):
        """(body, lattice point (a, b, c), points per axis) of particle i of a cube."""
        b = self.body_of(i)
        n = self.body_dims[b]
        r = i - self.body_start[b]
        return b, ti.Vector([r // (n[1] * n[2]), (r // n[2]) % n[1], r % n[2]]), n

    @ti.func
    def neighbour(self, i, b, c, dims, q):
        """(particle at direction q from particle i of a cube at lattice point c, whether it
        exists): i itself where none does."""
        t = c + self.offset[q]
        inside = (ti.min(t[0], t[1], t[2]) >= 0) & (t[0] < dims[0]) & (t[1] < dims[1]) & (t[2] < dims[2])
        return i + ti.select(inside, self.step[b * N_DIRECTIONS + q], 0), inside

    @ti.func
    def masked_neighbour(self, i, b, q):
        """(particle at direction q from particle i, whether it exists), from the presence mask: i
        itself where none does."""
        j = self.grid[self.grid_start[b] + self.point[i] + self.step[b * N_DIRECTIONS + q]]
        return ti.select(j >= 0, j, i), j >= 0

    @ti.func
    def any_neighbour(self, i, b, q):
        """``masked_neighbour`` with the presence mask, else ``neighbour``."""
        if ti.static(self.masked):
            return self.masked_neighbour(i, b, q)
        else:
            _, c, n = self.locate(i)
            return self.neighbour(i, b, c, n, q)

    @ti.func
    def _term(self, x: ti.template(), v: ti.template(), xi, vi, j, b, q):
        """Spring + damper force [N] on a particle at (xi, vi) of body b from neighbour j at direction q."""
        m = self.model
        e = b * N_DIRECTIONS + q
        g = spring_group(b, self.kind[q])
        d = xi - x[j]
        return spring_force(d, vi - v[j], d.norm(), self.rest[e], m.group_k[g], m.group_kd[g])

    @ti.func
    def force(self, x: ti.template(), v: ti.template(), i):
        """Sum of spring and damper forces [N] on particle i at state (x, v)."""
        xi, vi = x[i], v[i]
        f = ti.Vector.zero(float, 3)
        # Every direction sums in order; a missing neighbour is the particle itself (d = 0,
        # exactly zero force), so no loop has a branch.
        if ti.static(self.masked):
            b = self.body_of(i)
            for q in range(N_DIRECTIONS):
                j, _ = self.masked_neighbour(i, b, q)
                f += self._term(x, v, xi, vi, j, b, q)
        else:
            b, c, n = self.locate(i)
            # Every offset's components are at most INTERIOR_MARGIN in size: a particle that far
            # from every face has all 32 neighbours, so its loop tests none of them (most of a big
            # body's particles).
            if (ti.min(c[0], c[1], c[2]) >= INTERIOR_MARGIN) & (c[0] < n[0] - INTERIOR_MARGIN) \
                    & (c[1] < n[1] - INTERIOR_MARGIN) & (c[2] < n[2] - INTERIOR_MARGIN):
                for q in range(N_DIRECTIONS):
                    f += self._term(x, v, xi, vi, i + self.step[b * N_DIRECTIONS + q], b, q)
            else:
                for q in range(N_DIRECTIONS):
                    j, _ = self.neighbour(i, b, c, n, q)
                    f += self._term(x, v, xi, vi, j, b, q)
        return f

    @ti.func
    def add_spring_energy(self, x: ti.template(), out: ti.template(), k: ti.template()):
        """out[k] += elastic energy [J] of every spring, each once (its +offset direction); f64 sum.
        A top-level loop (``forces.Diagnostics``)."""
        m = self.model
        for i in range(m.n_particles):
            b = self.body_of(i)
            for h in range(N_DIRECTIONS // 2):
                q = 2 * h + 1  # the +offset directions
                j, there = self.any_neighbour(i, b, q)
                if there:
                    stretch = ti.cast((x[i] - x[j]).norm() - self.rest[b * N_DIRECTIONS + q], ti.f64)
                    kk = ti.cast(m.group_k[spring_group(b, self.kind[q])], ti.f64)
                    out[k] += 0.5 * kk * stretch * stretch


def lattice_stencil(model) -> LatticeStencil:
    """The model's ``LatticeStencil``, built on first use."""
    if model.stencil is None:
        model.stencil = LatticeStencil(model)
    return model.stencil


@ti.data_oriented
class StencilForces(ForceEvaluator):
    """``ForceEvaluator`` with the stencil pass: the same step-kernel pieces (``refresh`` and
    ``spring_pass`` do nothing; ``accel``), and ``compute``; allocates nothing per particle or spring."""

    def __init__(self, model, terrain, parallel: bool = False):
        self.model = model
        self.terrain = terrain
        self.strategy = NAME
        self.parallel = parallel
        self.rows = self.spring_f = self.kkd = None
        self.stencil = lattice_stencil(model)

    @ti.func
    def accel(self, x: ti.template(), v: ti.template(), i, dt):
        """Acceleration [m/s^2] of particle i at state (x, v)."""
        return self.particle_accel(x, v, i, self.stencil.force(x, v, i), dt)

    @ti.func
    def compute(self, x: ti.template(), v: ti.template(), dt, a: ti.template()):
        """a[i] = acceleration of every particle at (x, v) (a top-level loop)."""
        for i in range(self.model.n_particles):
            a[i] = self.accel(x, v, i, dt)
