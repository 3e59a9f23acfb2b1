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
lower id), so the two passes sum a particle's forces in the same order. Mesh bodies (clipped
lattices) are not supported: ``resolve`` refuses the choice for them (``check_lattice``).
"""

import numpy as np
import taichi as ti

from ..errors import UserError
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


def check_lattice(lattice: bool):
    """Refuse (``UserError``, one line) the stencil pass for a scene with a mesh body."""
    if not lattice:
        raise UserError("solver.forces = stencil: only cube bodies are supported (a mesh body's clipped "
                        "lattice is not); use gather or scatter")


@ti.data_oriented
class LatticeStencil:
    """A model's bodies as lattices, for index arithmetic: per body its first particle, n, spacing
    [m]; per body and direction the particle-index step and the rest length [m]. O(bodies) fields."""

    def __init__(self, model):
        check_lattice(model._lattice)
        self.model = model
        nb = max(len(model.bodies), 1)
        ends = np.array([info.particles.stop for info in model.bodies] or [0], np.int32)
        starts = np.array([info.particles.start for info in model.bodies] or [0], np.int32)
        ns = np.array([info.spec.n for info in model.bodies] or [1], np.int32)
        steps = np.zeros((nb, N_DIRECTIONS), np.int32)
        for b, n in enumerate(ns):
            for q, (_, o) in enumerate(DIRECTIONS):
                steps[b, q] = (o[0] * int(n) + o[1]) * int(n) + o[2]
        self.n_bodies = len(model.bodies)
        self.body_end = ti.field(ti.i32, nb)
        self.body_start = ti.field(ti.i32, nb)
        self.body_n = ti.field(ti.i32, nb)
        self.step = ti.field(ti.i32, nb * N_DIRECTIONS)
        self.rest = ti.field(float, nb * N_DIRECTIONS)
        self.offset = ti.Vector.field(3, ti.i32, N_DIRECTIONS)
        self.kind = ti.field(ti.i32, N_DIRECTIONS)
        self.body_end.from_numpy(ends)
        self.body_start.from_numpy(starts)
        self.body_n.from_numpy(ns)
        self.step.from_numpy(steps.ravel())
        self.offset.from_numpy(np.array([o for _, o in DIRECTIONS], np.int32))
        self.kind.from_numpy(np.array([k for k, _ in DIRECTIONS], np.int32))
        spacing = np.array([info.spec.size / (info.spec.n - 1) for info in model.bodies] or [1.0])
        self._fill_rest(spacing.astype(model.real))

    @ti.kernel
    def _fill_rest(self, h: ti.types.ndarray(ndim=1)):
        # As lattice.fill_springs computes it (the same rounding): h |o|.
        for e in range(self.n_bodies * N_DIRECTIONS):
            o = self.offset[e % N_DIRECTIONS]
            self.rest[e] = ti.cast(h[e // N_DIRECTIONS], float) * ti.sqrt(ti.cast(o.dot(o), float))

    @ti.func
    def locate(self, i):
        """(body, lattice point (a, b, c)) of particle i."""
        b = 0
        while i >= self.body_end[b]:
            b += 1
        n = self.body_n[b]
        r = i - self.body_start[b]
        return b, ti.Vector([r // (n * n), (r // n) % n, r % n]), n

    @ti.func
    def _term(self, x: ti.template(), v: ti.template(), xi, vi, i, j, b, q):
        """Spring + damper force [N] on particle i from direction q of body b, neighbour j."""
        m = self.model
        e = b * N_DIRECTIONS + q
        g = spring_group(b, self.kind[q])
        d = xi - x[j]
        return spring_force(d, vi - v[j], d.norm(), self.rest[e], m.group_k[g], m.group_kd[g])

    @ti.func
    def force(self, x: ti.template(), v: ti.template(), i):
        """Sum of spring and damper forces [N] on particle i at state (x, v)."""
        b, c, n = self.locate(i)
        xi, vi = x[i], v[i]
        f = ti.Vector.zero(float, 3)
        # Every offset's components are at most INTERIOR_MARGIN in size: a particle that far from
        # every face has all 32 neighbours, so its loop tests none of them (most of a big body's
        # particles); the others take the checked loop. Both sum in direction order.
        if (ti.min(c[0], c[1], c[2]) >= INTERIOR_MARGIN) & (ti.max(c[0], c[1], c[2]) < n - INTERIOR_MARGIN):
            for q in range(N_DIRECTIONS):
                f += self._term(x, v, xi, vi, i, i + self.step[b * N_DIRECTIONS + q], b, q)
        else:
            for q in range(N_DIRECTIONS):
                t = c + self.offset[q]
                inside = (ti.min(t[0], t[1], t[2]) >= 0) & (ti.max(t[0], t[1], t[2]) < n)
                # outside: the particle itself, d = 0 and exactly zero force
                j = i + ti.select(inside, self.step[b * N_DIRECTIONS + q], 0)
                f += self._term(x, v, xi, vi, i, j, b, q)
        return f

    @ti.func
    def add_spring_energy(self, x: ti.template(), out: ti.template(), k: ti.template()):
        """out[k] += elastic energy [J] of every spring, each once (its +offset direction); f64 sum.
        A top-level loop (``forces.Diagnostics``)."""
        m = self.model
        for i in range(m.n_particles):
            b, c, n = self.locate(i)
            for h in range(N_DIRECTIONS // 2):
                q = 2 * h + 1  # the +offset directions
                t = c + self.offset[q]
                if ti.min(t[0], t[1], t[2]) >= 0 and ti.max(t[0], t[1], t[2]) < n:
                    e = b * N_DIRECTIONS + q
                    stretch = ti.cast((x[i] - x[i + self.step[e]]).norm() - self.rest[e], ti.f64)
                    kk = ti.cast(m.group_k[spring_group(b, self.kind[q])], ti.f64)
                    out[k] += 0.5 * kk * stretch * stretch


def lattice_stencil(model) -> LatticeStencil:
    """The model's ``LatticeStencil``, built on first use (``UserError`` for a mesh body)."""
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
