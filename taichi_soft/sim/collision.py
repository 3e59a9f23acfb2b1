"""Contact between different bodies: particle-particle collision through a uniform-grid hash.

Only scenes with more than one body build a ``BodyContacts`` (a one-body scene compiles none of
this code). Each particle is a sphere of radius half its body's lattice spacing, so two bodies
touch when particles of different bodies come closer than the sum of their radii: one lattice
spacing for equal cubes. That is enough to block a particle from passing through a face of the
other lattice (it would have to come within 0.71 spacings of a face's particles); a body with a
much coarser lattice than its neighbour (over ~1.4x the spacing) could let the finer one's
particles through its faces.

After every step (``Integrator._body_contacts``) the pass

1. finds each body's bounding box; only particles within the contact distance of another
   body's box can touch it (bodies apart cost a few passes over the particles, no hash lookups);
   those are hashed into a cell of edge ``cell`` (the largest contact distance) in a table of
   ``CELL_CAPACITY`` slots per bucket; a particle that finds its bucket full is not seen by
   others this step and is counted in ``overflows``;
2. counts each particle's contacts (particles of other bodies closer than r_i + r_j);
3. computes, per pair, a position correction that removes the overlap and a velocity impulse on
   the relative velocity with the terrain's contact model: restitution only above the bounce
   threshold, Coulomb friction mu |dv_N| on the tangential relative velocity, never reversing
   it (body-body friction always acts on the impulse: there is no force-level contact between
   bodies). Pair corrections are split by inverse mass and scaled by 1 / max(contacts of i,
   contacts of j), the same for both particles of a pair, so momentum is conserved exactly and
   a particle in many contacts is not over-corrected;
4. applies the corrections.
"""

import numpy as np
import taichi as ti

CELL_CAPACITY = 16  # particle slots per hash bucket
# Jacobi sweeps of the velocity impulses per step: with relaxed (averaged) impulses one sweep
# leaves most of a resting particle's approach in place and the stack jitters; four settle it.
VELOCITY_ITERATIONS = 4
_COUNT, _VELOCITY, _POSITION = 0, 1, 2


def table_size(n_particles: int) -> int:
    """Hash buckets for ``n_particles``: a power of two, at least 2 per particle."""
    return 1 << max(int(np.ceil(np.log2(2 * n_particles))), 4)


def field_bytes(n_particles: int, real_bytes: int) -> int:
    """Bytes of a ``BodyContacts``'s fields (for the memory model): per bucket a count and
    ``CELL_CAPACITY`` slots; per particle body, near flag, contact count (i32), radius and dx, dv
    (reals)."""
    return table_size(n_particles) * (1 + CELL_CAPACITY) * 4 + n_particles * (3 * 4 + 7 * real_bytes)


def body_radius(spec) -> float:
    """Contact radius [m] of a body's particles: half its lattice spacing."""
    return 0.5 * spec.size / (spec.n - 1)


def contact_radii(model) -> np.ndarray:
    """Contact radius [m] of every particle (``body_radius`` of its body)."""
    r = np.zeros(model.n_particles)
    for body in model.bodies:
        r[body.particles] = body_radius(body.spec)
    return r


@ti.data_oriented
class BodyGrid:
    """What both body-contact solvers share (this module's, after the step; the implicit solvers'
    pairs, in it): each particle's body and contact radius, each body's bounding box, the particles
    near another body, and the spatial hash's cells and buckets (edge ``cell`` [m])."""

    def _init_grid(self, model):
        n = model.n_particles
        self.n = n
        self.table_size = table_size(n)
        self.n_bodies = len(model.bodies)
        self.body = ti.field(ti.i32, n)
        self.radius = ti.field(float, n)
        self.near = ti.field(ti.i32, n)  # 1: within ``cell`` of another body's box
        self.lo = ti.Vector.field(3, float, self.n_bodies)  # bounding box of each body [m]
        self.hi = ti.Vector.field(3, float, self.n_bodies)
        self.cell = ti.field(float, ())  # hash cell edge [m]
        body = np.zeros(n, np.int32)
        for b, info in enumerate(model.bodies):
            body[info.particles] = b
        self.body.from_numpy(body)
        radii = contact_radii(model)
        self.radius.from_numpy(radii.astype(model.real))
        return radii

    @ti.func
    def _cell_of(self, p):
        return ti.floor(p / self.cell[None], ti.i32)

    @ti.func
    def _bucket(self, c):
        # Teschner et al. 2003 spatial hash; i32 products wrap, the mask keeps it in range.
        h = (c.x * 73856093) ^ (c.y * 19349663) ^ (c.z * 83492791)
        return h & (self.table_size - 1)

    @ti.func
    def _mark_near(self, x: ti.template()):
        """Each body's bounding box at ``x``, then ``near`` = 1 for the particles within ``cell`` of
        another body's box: only those are hashed (bodies apart cost a few passes, no lookups)."""
        for b in range(self.n_bodies):
            self.lo[b] = ti.Vector([1e30, 1e30, 1e30], dt=float)
            self.hi[b] = ti.Vector([-1e30, -1e30, -1e30], dt=float)
        for i in range(self.n):
            b = self.body[i]
            for c in ti.static(range(3)):
                ti.atomic_min(self.lo[b][c], x[i][c])
                ti.atomic_max(self.hi[b][c], x[i][c])
        for i in range(self.n):
            self.near[i] = 0
            xi, reach = x[i], self.cell[None]
            for b in range(self.n_bodies):
                if b != self.body[i] and all(xi >= self.lo[b] - reach) and all(xi <= self.hi[b] + reach):
                    self.near[i] = 1


@ti.data_oriented
class BodyContacts(BodyGrid):
    """Particle-particle contact between different bodies of ``model``; coefficients from ``terrain``
    (restitution, friction, bounce threshold: the scene's ``[contact]`` table)."""

    def __init__(self, model, terrain):
        self.model = model
        self.terrain = terrain
        radii = self._init_grid(model)
        n = self.n
        self.count = ti.field(ti.i32, self.table_size)
        self.slots = ti.field(ti.i32, (self.table_size, CELL_CAPACITY))
        self.contacts = ti.field(ti.i32, n)
        self.dx = ti.Vector.field(3, float, n)
        self.dv = ti.Vector.field(3, float, n)
        self.overflows = ti.field(ti.i64, ())  # particles not hashed (bucket full), summed over steps
        self.pairs = ti.field(ti.i64, ())  # contact pairs seen, summed over steps
        self.cell[None] = 2.0 * float(radii.max())  # the largest contact distance

    def stats(self) -> dict:
        """Counters for the run summary: contact pairs and hash overflows, summed over all steps."""
        return {"body_contact_pairs": int(self.pairs[None]), "body_contact_overflows": int(self.overflows[None])}

    def reset(self):
        self.overflows[None] = 0
        self.pairs[None] = 0

    @ti.func
    def apply(self, x: ti.template(), v: ti.template(), dt):
        """Resolve contacts between bodies at state (x, v) in place (one pass, see module doc)."""
        self._mark_near(x)
        for h in range(self.table_size):
            self.count[h] = 0
        for i in range(self.n):
            if self.near[i]:
                h = self._bucket(self._cell_of(x[i]))
                k = ti.atomic_add(self.count[h], 1)
                if k < CELL_CAPACITY:
                    self.slots[h, k] = i
                else:
                    ti.atomic_add(self.overflows[None], 1)
        for i in range(self.n):
            self.contacts[i] = 0
            if self.near[i]:
                self.contacts[i] = self._visit(x, v, i, _COUNT)
        for _ in ti.static(range(VELOCITY_ITERATIONS)):
            for i in range(self.n):
                if self.contacts[i] > 0:
                    self._visit(x, v, i, _VELOCITY)
            for i in range(self.n):
                if self.contacts[i] > 0:
                    v[i] += self.dv[i]
        for i in range(self.n):
            if self.contacts[i] > 0:
                self._visit(x, v, i, _POSITION)
        for i in range(self.n):
            if self.contacts[i] > 0:
                x[i] += self.dx[i]

    @ti.func
    def _visit(self, x: ti.template(), v: ti.template(), i, what: ti.template()):
        """Particle i's contacts: count them (``_COUNT``, returned), or store the sum of its
        velocity (``_VELOCITY``, in ``dv``) or position (``_POSITION``, in ``dx``) corrections."""
        xi, bi, ri = x[i], self.body[i], self.radius[i]
        ci = self._cell_of(xi)
        found = 0
        corr = ti.Vector.zero(float, 3)
        for o in range(27):  # the 3x3x3 cells around i's (a run-time loop: unrolled, it compiles for a minute)
            c = ci + ti.Vector([o // 9 - 1, (o // 3) % 3 - 1, o % 3 - 1])
            h = self._bucket(c)
            for k in range(ti.min(self.count[h], CELL_CAPACITY)):
                j = self.slots[h, k]
                # Buckets are shared by distant cells (and two neighbour cells may share one):
                # take j only from the cell it really lies in, so each pair is seen once.
                if self.body[j] != bi and all(self._cell_of(x[j]) == c):
                    d = xi - x[j]
                    dist = d.norm()
                    reach = ri + self.radius[j]
                    if dist < reach:
                        found += 1
                        if ti.static(what != _COUNT):
                            n = ti.Vector([0.0, 1.0, 0.0], dt=float)
                            if dist > 0:
                                n = d / dist
                            inv_i, inv_j = self.model.inv_mass[i], self.model.inv_mass[j]
                            # i's share of the pair's correction, the same relaxation for both ends.
                            share = inv_i / ti.max(inv_i + inv_j, 1e-30) / ti.cast(
                                ti.max(self.contacts[i], self.contacts[j]), float)
                            if ti.static(what == _POSITION):
                                corr += (share * (reach - dist)) * n
                            else:
                                corr += share * self._impulse(v[i] - v[j], n)
        if ti.static(what == _COUNT):
            ti.atomic_add(self.pairs[None], found)
        elif ti.static(what == _VELOCITY):
            self.dv[i] = corr
        else:
            self.dx[i] = corr
        return found

    @ti.func
    def _impulse(self, rel, n):
        """Change [m/s] of the relative velocity ``rel`` of a pair in contact along unit normal n:
        the terrain's impact response (restitution above the bounce threshold, Coulomb friction on
        the impulse, never reversing), always with friction."""
        dv = ti.Vector.zero(float, 3)
        vn = rel.dot(n)
        if vn < 0:
            dv = self.terrain.impact_response(rel, n, vn, 1) - rel
        return dv
