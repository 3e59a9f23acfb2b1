"""Contact between different bodies: particle-particle collision through a uniform-grid hash.

Only scenes with more than one body build a ``BodyContacts`` (a one-body scene compiles none of
this code). Each particle has a contact radius of half its body's lattice spacing; a pair (i, j)
of particles of different bodies has a contact distance R_ij = r_i + r_j (one spacing for equal
cubes) and a unit normal n from j toward i (``BodyGrid._pair_normal``):

* **On a face** (i or j lies on a face of its body, ``face_normals``): n is the outward normal of
  the particle's face that best faces the other particle (of an edge's two faces, a corner's
  three), turned with its body's best-fit rotation at the start of the step; both on faces: the
  normalised difference of the two. The pair overlaps by o = R_ij - n . (x_i - x_j), weighted by
  w = (1 - |t|^2 / s^2)^2 of the tangential offset t within the face's spacing s: over a flat face
  the weights of the face's particles sum to 1-1.125 wherever a particle is, and the gap along n is
  the same for all of them, so the face is flat: a body slides on another's face at mu g
  (``bench contact``: 2.94 m/s^2 at mu = 0.3, 0.00 at mu = 0; spheres made a bumpy
  surface whose hollows held a sliding body, 7.3 m/s^2 at mu = 0).
* **Otherwise** (two faces that face the same way, or a particle inside its body): spheres,
  o = R_ij - |x_i - x_j|, n along x_i - x_j, w = 1.

Two bodies touch at most at the distance sqrt(R_ij^2 + s^2) <= ``SPAN`` x 2 r_max, which sizes the
hash cells. A particle passing through a face would have to come within 0.71 spacings of a face's
particles; a body with a much coarser lattice than its neighbour (over ~1.4x the spacing) could let
the finer one's particles through its edges. Faces cost more than spheres, mostly the larger hash
cells (docs/decisions/body-contact-face-normals.md). The implicit solvers' contact inside the step (``integrators/implicit/pairs.py``)
uses the same geometry (``BodyGrid``), with each pair's normal and face frozen for the step and an
edge particle's face normals blended (``_blended_face_normal``) rather than the best one chosen.

After every step (``Integrator._body_contacts``) the pass

1. finds each body's bounding box; only particles within the contact distance of another
   body's box can touch it (bodies apart cost a few passes over the particles, no hash lookups);
   those are hashed into a cell of edge ``cell`` (the largest contact distance) in a table of
   ``CELL_CAPACITY`` slots per bucket; a particle that finds its bucket full is not seen by
   others this step and is counted in ``overflows``;
2. sums each particle's contact weights W (pairs with o > 0, weighted by w);
3. computes, per pair, a position correction that removes the overlap and a velocity impulse on
   the relative velocity with the terrain's contact model: restitution only above the bounce
   threshold, Coulomb friction mu |dv_N| on the tangential relative velocity, never reversing
   it (body-body friction always acts on the impulse: there is no force-level contact between
   bodies). Pair corrections are split by inverse mass and scaled by w / max(W_i, W_j, 1), the
   same for both particles of a pair, so momentum is conserved exactly and a particle in many
   contacts is not over-corrected;
4. applies the corrections.
"""

import numpy as np
import taichi as ti

from ..face_normals import rest_frames

CELL_CAPACITY = 16  # particle slots per hash bucket
# Jacobi sweeps of the velocity impulses per step: with relaxed (averaged) impulses one sweep
# leaves most of a resting particle's approach in place and the stack jitters; four settle it.
VELOCITY_ITERATIONS = 4
_COUNT, _VELOCITY, _POSITION = 0, 1, 2
SPAN = float(np.sqrt(2.0))  # largest contact distance / (2 r_max): a face pair's sqrt(R^2 + s^2)


def table_size(n_particles: int) -> int:
    """Hash buckets for ``n_particles``: a power of two, at least 2 per particle."""
    return 1 << max(int(np.ceil(np.log2(2 * n_particles))), 4)


def field_bytes(n_particles: int, real_bytes: int) -> int:
    """Bytes of a ``BodyContacts``'s fields (for the memory model): per bucket a count and
    ``CELL_CAPACITY`` slots; per particle body, near flag and face mask (i32), radius, contact
    weight, dx, dv and rest position (reals). Per body fields (boxes, rotations): a few hundred
    bytes, left out."""
    return table_size(n_particles) * (1 + CELL_CAPACITY) * 4 + n_particles * (3 * 4 + 11 * real_bytes)


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
    pairs, in it): each particle's body, contact radius, face mask and rest position, each body's
    bounding box and best-fit rotation, the particles near another body, the spatial hash's cells
    and buckets (edge ``cell`` [m]), and a pair's contact geometry (module doc: normal, overlap,
    weight)."""

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
        rest, faces = rest_frames(model)
        self.rest = ti.Vector.field(3, float, n)  # rest position about the body's mean [m]
        self.faces = ti.field(ti.i32, n)  # face mask (face_normals.AXES bits; 0: inside the body)
        self.first = ti.field(ti.i32, self.n_bodies + 1)  # body b: particles first[b] .. first[b + 1] - 1
        self.turn = ti.Matrix.field(3, 3, float, self.n_bodies)  # best-fit rotation of each body
        self.rest.from_numpy(rest.astype(model.real))
        self.faces.from_numpy(faces)
        self.first.from_numpy(np.array([b.particles.start for b in model.bodies] + [n], np.int32))
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

    @ti.func
    def _turn_normals(self, x: ti.template()):
        """``turn`` = the best-fit rotation at x (the polar factor of sum (x_i - c) X_i^T, X the rest
        positions) of each body with a particle ``near`` another body (only those meet pairs),
        which turns its face normals: lagged, once per step. The sums run serially within a body,
        so repeat runs give the same bits; a body apart costs one scan of its near flags."""
        for b in range(self.n_bodies):
            lo, hi = self.first[b], self.first[b + 1]
            touching = 0
            for i in range(lo, hi):
                if self.near[i]:
                    touching = 1
                    break
            if touching:
                c = ti.Vector.zero(float, 3)
                for i in range(lo, hi):
                    c += x[i]
                c /= ti.cast(hi - lo, float)
                a = ti.Matrix.zero(float, 3, 3)
                for i in range(lo, hi):
                    a += (x[i] - c).outer_product(self.rest[i])
                u, _p = ti.polar_decompose(a)
                self.turn[b] = u

    @ti.func
    def _axis_normal(self, i, a: ti.template()):
        """The outward normal of face a (``face_normals.AXES``) of particle i's body, turned with the
        body's rotation: column a % 3 of the rotation, positive for a < 3."""
        turn = self.turn[self.body[i]]
        return ti.static(1.0 - 2.0 * (a // 3)) * ti.Vector([turn[0, a % 3], turn[1, a % 3], turn[2, a % 3]])

    @ti.func
    def _face_normal(self, i, toward):
        """The outward normal (turned) of particle i's face that best faces direction ``toward``; zero
        for a particle inside its body."""
        best = ti.Vector.zero(float, 3)
        score = ti.cast(-2.0, float)
        mask = self.faces[i]
        for a in ti.static(range(6)):
            if mask & (1 << a):
                n = self._axis_normal(i, a)
                c = n.dot(toward)
                if c > score:
                    score = c
                    best = n
        return best

    @ti.func
    def _blended_face_normal(self, i, toward, sharpness: ti.template()):
        """Particle i's outward face normals (turned), blended with weights exp(sharpness c_a), c_a the
        cosine between face a's normal and direction ``toward``, and normalised. A particle on one
        face gets that face's normal. On an edge or a corner the normal turns continuously with
        ``toward``, close to ``_face_normal``'s choice wherever one face faces clearly better.
        Zero for a particle inside its body."""
        u = toward / ti.max(toward.norm(), 1e-30)
        mask = self.faces[i]
        top = ti.cast(-2.0, float)
        for a in ti.static(range(6)):
            if mask & (1 << a):
                top = ti.max(top, self._axis_normal(i, a).dot(u))
        blend = ti.Vector.zero(float, 3)
        for a in ti.static(range(6)):
            if mask & (1 << a):
                n = self._axis_normal(i, a)
                blend += ti.exp(sharpness * (n.dot(u) - top)) * n
        out = ti.Vector.zero(float, 3)
        if blend.norm_sqr() > 0.25:
            out = blend.normalized()
        else:  # (opposite faces of a one-layer mesh body can cancel: keep the best; none inside the body)
            out = self._face_normal(i, toward)
        return out

    @ti.func
    def _pair_normal(self, i, j, d, dist):
        """Contact normal of the pair (i, j) at d = x_i - x_j, dist = |d| (unit, from j toward i) and
        its face spacing s [m]: s > 0 for a pair on a face (module doc), 0 for a pair of spheres."""
        return self._normal_between(i, j, self._face_normal(i, -d), self._face_normal(j, d), d, dist)

    @ti.func
    def _blended_pair_normal(self, i, j, d, dist, sharpness: ti.template()):
        """``_pair_normal`` with each particle's face normal blended (``_blended_face_normal``)."""
        return self._normal_between(i, j, self._blended_face_normal(i, -d, sharpness),
                                    self._blended_face_normal(j, d, sharpness), d, dist)

    @ti.func
    def _normal_between(self, i, j, ni, nj, d, dist):
        """``_pair_normal`` from particle i's face normal ni (facing j) and j's nj (facing i), zero
        where a particle lies inside its body."""
        fi = ni.norm_sqr() > 0.5
        fj = nj.norm_sqr() > 0.5
        n = ti.Vector([0.0, 1.0, 0.0], dt=float)
        s = ti.cast(0.0, float)
        if fi and fj and (nj - ni).norm_sqr() > 0.25:  # faces not facing the same way
            n = (nj - ni).normalized()
            s = 2.0 * ti.max(self.radius[i], self.radius[j])
        elif fj and not fi:
            n = nj
            s = 2.0 * self.radius[j]
        elif fi and not fj:
            n = -ni
            s = 2.0 * self.radius[i]
        elif dist > 0:
            n = d / dist
        return n, s

    @ti.func
    def _pair_gap(self, i, j, d, dist, n, s):
        """(overlap o [m], weight w) of the pair (i, j) at d = x_i - x_j, dist = |d|, with normal n
        and face spacing s (``_pair_normal``); in contact when o > 0 and w > 0."""
        reach = self.radius[i] + self.radius[j]
        o = reach - dist
        w = ti.cast(1.0, float)
        if s > 0:
            dn = n.dot(d)
            t = d - dn * n
            q = ti.max(1.0 - t.norm_sqr() / (s * s), 0.0)
            o = reach - dn
            w = q * q
        return o, w

    @ti.func
    def _span(self, i, j):
        """Largest distance [m] at which particles i and j of different bodies can touch."""
        reach = self.radius[i] + self.radius[j]
        s = 2.0 * ti.max(self.radius[i], self.radius[j])
        return ti.sqrt(reach * reach + s * s)


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
        self.weight = ti.field(float, n)  # sum of the weights w of the particle's pairs in contact
        self.dx = ti.Vector.field(3, float, n)
        self.dv = ti.Vector.field(3, float, n)
        self.overflows = ti.field(ti.i64, ())  # particles not hashed (bucket full), summed over steps
        self.pairs = ti.field(ti.i64, ())  # contact pairs seen, summed over steps
        self.cell[None] = SPAN * 2.0 * float(radii.max())  # the largest contact distance

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
        self._turn_normals(x)
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
            self.weight[i] = 0.0
            if self.near[i]:
                self._visit(x, v, i, _COUNT)
        for _ in ti.static(range(VELOCITY_ITERATIONS)):
            for i in range(self.n):
                if self.weight[i] > 0:
                    self._visit(x, v, i, _VELOCITY)
            for i in range(self.n):
                if self.weight[i] > 0:
                    v[i] += self.dv[i]
        for i in range(self.n):
            if self.weight[i] > 0:
                self._visit(x, v, i, _POSITION)
        for i in range(self.n):
            if self.weight[i] > 0:
                x[i] += self.dx[i]

    @ti.func
    def _visit(self, x: ti.template(), v: ti.template(), i, what: ti.template()):
        """Particle i's contacts: sum their weights (``_COUNT``, in ``weight``), or store the sum of its
        velocity (``_VELOCITY``, in ``dv``) or position (``_POSITION``, in ``dx``) corrections."""
        xi, bi = x[i], self.body[i]
        ci = self._cell_of(xi)
        found = 0
        total = ti.cast(0.0, float)
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
                    if dist < self._span(i, j):
                        n, s = self._pair_normal(i, j, d, dist)
                        ov, w = self._pair_gap(i, j, d, dist, n, s)
                        if ov > 0 and w > 0:
                            found += 1
                            total += w
                            if ti.static(what != _COUNT):
                                inv_i, inv_j = self.model.inv_mass[i], self.model.inv_mass[j]
                                # i's share of the pair's correction, the same relaxation for both ends.
                                share = w * inv_i / ti.max(inv_i + inv_j, 1e-30) / ti.max(
                                    ti.max(self.weight[i], self.weight[j]), 1.0)
                                if ti.static(what == _POSITION):
                                    corr += (share * ov) * n
                                else:
                                    corr += share * self._impulse(v[i] - v[j], n)
        if ti.static(what == _COUNT):
            ti.atomic_add(self.pairs[None], found)
            self.weight[i] = total
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
