"""The candidate pairs of body-body contact inside the implicit step, and the tube that keeps them complete.

``PairContacts`` (pairs.py) computes the contact terms over a list of candidate pairs; this base
class builds the list. The rule (docs/implicit.md, "Contact between bodies"):

* **The tube.** Every trial point the solver evaluates lies on a segment: the reference x_n and the
  feasible start's trials on the start paths x_n + u0 + t d (u0 the pinned particles' fixed move,
  d the start direction, t the start fraction), every later trial on x_k + alpha dx (the current
  iterate and the search direction). The list is built for a tube around one such family of paths,
  P_i(t) = x_n + ``base``_i + t ``path``_i, t in [0, 1], radius ``RHO`` = R_max / 4: a trial is
  inside if one common t puts every free particle within RHO of P_i(t) (``track``: each particle's
  admissible t form an interval; the tube is their intersection, a convex set).
* **Complete for the tube.** For a trial inside, x_i - x_j lies within 2 RHO of a + t b
  (a = P_i(0) - P_j(0), b = path_i - path_j), so a pair whose relative path {a + t b, t in [0, 1]}
  stays at least S_ij + 2 RHO from the origin cannot touch there (S_ij the farthest the pair can
  touch: R_ij for spheres, sqrt(R_ij^2 + s^2) on a face, ``BodyGrid._span``): the candidates are
  the other pairs (``_collect``). The test is on the relative path, so bodies that move together (a falling
  pile) or apart are not candidates however fast they move, and the list holds about the pairs
  that do come into contact.
* **Following the solver.** The step's list is built along the start paths (``begin``). When a
  search direction would take the full step x_k + dx out of the tube (``follow``), the list is
  rebuilt along x_k + alpha dx; the old list's frozen friction multipliers carry over to the same
  pairs (``_stash``, ``_restore``; a pair holding one that the new list lacks, apart by more than
  its reach all along the new path, loses it: its friction term, zero at x_n and never negative,
  leaves the objective). The next step's list takes each pair's end-of-step load the same way. A trial off its tube all
  the same (the terrain's projection can move a particle off its segment) is rejected and counted,
  never let through. The list holds ``PAIRS_PER_PARTICLE`` per particle; more is counted
  (``body_pair_overflows``) and said by ``health``.
"""

import taichi as ti

from ...contact.bodies import SPAN, BodyGrid, table_size

# Capacity of the candidate list per particle (overflow is counted). The tube's list holds about the
# pairs in contact: the pile scene needs under 1 per particle at 1/60 s and at 0.1 s
# (docs/benchmarks/ENERGY.md).
PAIRS_PER_PARTICLE = 12
RHO = 0.25  # tube radius, in units of the largest contact distance R_max
# How sharply a pair's normal follows the faces of an edge or corner particle
# (``BodyGrid._blended_face_normal``): the normal is frozen for a step, and a best-facing face that
# jumps between steps adds penalty energy at steps' starts; sharper blends add more, softer ones round
# the faces' edges and add friction (docs/decisions/body-contact-face-normals.md).
FACE_BLEND = 4.0


def field_bytes(n_particles: int, real_bytes: int) -> int:
    """Bytes of a ``PairContacts``'s fields (for the memory model): per candidate pair two ends (i32),
    a multiplier, its normal, the contact normal and face spacing and a 3x3 block (reals), and the
    carried-over copy of a partner (i32), a multiplier and a normal (reals); per particle body, near
    flag, face mask, sorted index, contact count, two carry-over counters and two candidate counters (i32), radius, rest
    position, gradient, restitution, contact weight and depth, tube base, path and midpoint and a
    3x3 block (reals); per hash
    bucket a count and a start (i32)."""
    pairs = PAIRS_PER_PARTICLE * n_particles * (3 * 4 + 21 * real_bytes)
    return pairs + n_particles * (9 * 4 + 30 * real_bytes) + table_size(n_particles) * 2 * 4


@ti.data_oriented
class PairList(BodyGrid):
    """Candidate pairs of the bodies of ``model`` for the tube of the step whose ``objective`` (u, dx,
    x_prev) the subclass holds (module doc)."""

    def _init_list(self, model):
        n = model.n_particles
        radii = self._init_grid(model)
        self.capacity = max(1, int(round(PAIRS_PER_PARTICLE * n)))
        vec = lambda size: ti.Vector.field(3, float, size)  # noqa: E731
        self.r_max = ti.field(float, ())  # largest contact distance R_ij [m]
        self.r_max[None] = 2.0 * float(radii.max())
        self.base = vec(n)  # the tube: P_i(t) = x_n + base_i + t path_i [m]
        self.path = vec(n)
        self.mid = vec(n)  # P_i(1/2), where the particle is hashed [m]
        self.d_lo = ti.Vector.field(3, float, ())  # box of all path vectors [m]
        self.d_hi = ti.Vector.field(3, float, ())
        self.t_lo = ti.field(float, ())  # the common path parameters the last trial's particles
        self.t_hi = ti.field(float, ())  # admit, [t_lo, t_hi] (``track``)
        self.again = ti.field(ti.i32, ())  # 1: the search direction leaves the tube (``follow``)
        self.bucket_count = ti.field(ti.i32, self.table_size)
        self.bucket_start = ti.field(ti.i32, self.table_size + 1)
        self.sorted = ti.field(ti.i32, n)
        self.n_pairs = ti.field(ti.i32, ())
        self.pa = ti.field(ti.i32, self.capacity)  # pa < pb
        self.pb = ti.field(ti.i32, self.capacity)
        # Frozen friction multiplier h^2 |F_n| [kg m]; between steps, the load of the step's end.
        self.lam = ti.field(float, self.capacity)
        self.fnormal = vec(self.capacity)  # the normal frozen with it
        self.pnormal = vec(self.capacity)  # contact normal of a face pair, frozen at x_n (``_geometry``)
        self.pspace = ti.field(float, self.capacity)  # its face spacing s [m]; 0: a pair of spheres
        self.keep_pb = ti.field(ti.i32, self.capacity)  # the held pairs of the old list, by pa
        self.keep_lam = ti.field(float, self.capacity)
        self.keep_normal = vec(self.capacity)
        self.keep_count = ti.field(ti.i32, n)
        self.keep_start = ti.field(ti.i32, n + 1)
        self.found_count = ti.field(ti.i32, n)  # each particle's candidates, counted before they are written
        self.found_start = ti.field(ti.i32, n + 1)
        return radii

    # -- the tube -------------------------------------------------------------------------------
    @ti.func
    def _rho(self):
        return RHO * self.r_max[None]

    @ti.func
    def _admit(self, i, w):
        """Narrow [t_lo, t_hi] to the t with |w - t path_i| <= RHO, w = particle i's displacement
        from x_n + base_i [m]."""
        rho = self._rho()
        d = self.path[i]
        dd = d.dot(d)
        wd = w.dot(d)
        cc = w.dot(w) - rho * rho
        if dd > 0:
            disc = wd * wd - dd * cc
            if disc >= 0:
                root = ti.sqrt(disc)
                ti.atomic_max(self.t_lo[None], (wd - root) / dd)
                ti.atomic_min(self.t_hi[None], (wd + root) / dd)
            else:
                ti.atomic_max(self.t_lo[None], 2.0)
        elif cc > 0:
            ti.atomic_max(self.t_lo[None], 2.0)

    @ti.func
    def trial_begin(self):
        self.t_lo[None] = 0.0
        self.t_hi[None] = 1.0

    @ti.func
    def track(self, i, ui):
        """Record free particle i's trial displacement ``ui`` from x_n [m] (the tube)."""
        self._admit(i, ui - self.base[i])

    @ti.func
    def outside(self):
        """The trial tracked since ``trial_begin`` lies outside the tube."""
        return self.t_lo[None] > self.t_hi[None]

    @ti.func
    def check(self):
        """``again`` = 1 if the step's full update u + dx leaves the tube (the tube is convex and holds
        u, so then and only then can a trial of the line search leave it, projection aside)."""
        ob = self.objective
        self.trial_begin()
        for i in range(self.n):
            if self.model.free(i):
                self._admit(i, ob.u[i] + ob.dx[i] - self.base[i])
        self.again[None] = 0
        if self.outside():
            self.again[None] = 1

    @ti.func
    def regather(self):
        """Rebuild the list along u + alpha dx (the tube around the line search), carrying the held
        pairs' frozen friction multipliers and normals over."""
        ob = self.objective
        self._stash()
        for i in range(self.n):
            self.base[i] = ob.u[i]
            self.path[i] = ob.dx[i]
        self._collect(ob.x_prev)
        self._restore(1.0)
        self.acc.gathers[None] += 1.0

    @ti.func
    def _stash(self):
        """Keep the pairs holding a friction multiplier (``lam`` > 0), with it and its normal, by
        their first particle: the list is about to be rebuilt."""
        for i in range(self.n):
            self.keep_count[i] = 0
        for p in range(self.n_pairs[None]):
            if self.lam[p] > 0:
                ti.atomic_add(self.keep_count[self.pa[p]], 1)
        _starts(self.keep_count, self.keep_start, self.n)
        for p in range(self.n_pairs[None]):
            if self.lam[p] > 0:
                i = self.pa[p]
                k = self.keep_start[i] + ti.atomic_add(self.keep_count[i], 1)
                self.keep_pb[k] = self.pb[p]
                self.keep_lam[k] = self.lam[p]
                self.keep_normal[k] = self.fnormal[p]

    @ti.func
    def _restore(self, scale):
        """Give each pair of the rebuilt list its stashed multiplier (times ``scale``) and normal, or
        none."""
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            self.lam[p] = 0.0
            for k in range(self.keep_start[i], self.keep_start[i + 1]):
                if self.keep_pb[k] == j:
                    self.lam[p] = scale * self.keep_lam[k]
                    self.fnormal[p] = self.keep_normal[k]

    # -- the list -------------------------------------------------------------------------------
    @ti.func
    def _collect(self, xp: ti.template()):
        """The candidates of the tube around x_n = ``xp`` + base + t path (module doc), hashed at the
        paths' midpoints."""
        rho = self._rho()
        for c in ti.static(range(3)):
            self.d_lo[None][c] = 1e30
            self.d_hi[None][c] = -1e30
        for i in range(self.n):
            d = self.path[i]
            self.mid[i] = xp[i] + self.base[i] + 0.5 * d
            for c in ti.static(range(3)):
                ti.atomic_min(self.d_lo[None][c], d[c])
                ti.atomic_max(self.d_hi[None][c], d[c])
        # A candidate has |a + t b| < S_ij + 2 RHO for some t (S_ij = ``_span``, at most SPAN R_max),
        # and |b| <= 2 D (D the half-diagonal of the box of all path vectors), so
        # |mid_i - mid_j| = |a + b / 2| < SPAN R_max + 2 RHO + D: the cell.
        # The box is read back a component at a time, as the atomics wrote it. Read as whole vectors,
        # the optimised one-launch step (serial driver, Taichi 1.7.4's IR passes on) got the values
        # of the step's first list, built along the start paths: a rebuilt list's cells were sized
        # for the wrong moves and missed pairs in contact (reduced in
        # scripts/taichi_stale_vector_read.py, and the pass at fault is now off everywhere,
        # runtime.CACHE_LOOP_INVARIANTS; tests/test_body_contact_implicit.py runs it optimised).
        extent2 = ti.cast(0.0, float)
        for c in ti.static(range(3)):
            extent2 += (self.d_hi[None][c] - self.d_lo[None][c]) ** 2
        self.cell[None] = SPAN * self.r_max[None] + 2.0 * rho + 0.5 * ti.sqrt(extent2)
        self._mark_near(self.mid)
        for h in range(self.table_size):
            self.bucket_count[h] = 0
        for i in range(self.n):
            if self.near[i]:
                ti.atomic_add(self.bucket_count[self._bucket(self._cell_of(self.mid[i]))], 1)
        _starts(self.bucket_count, self.bucket_start, self.table_size)
        for i in range(self.n):
            if self.near[i]:
                h = self._bucket(self._cell_of(self.mid[i]))
                k = ti.atomic_add(self.bucket_count[h], 1)
                self.sorted[self.bucket_start[h] + k] = i
        # Counted, then written from each particle's own start: no atomic inside _find's run-time
        # loops (on Vulkan, lavapipe, an integer atomic there ended the loop early and the list
        # stayed empty: scripts/vulkan_atomic_in_loop.py). The order is the serial append's.
        for i in range(self.n):
            self.found_count[i] = 0
            if self.near[i]:
                self.found_count[i] = self._find(i, rho, 0, False)
        _starts(self.found_count, self.found_start, self.n)
        for i in range(self.n):
            if self.near[i]:
                self._find(i, rho, self.found_start[i], True)
        total = self.found_start[self.n]
        self.acc.overflow[None] += ti.cast(ti.max(total - self.capacity, 0), ti.f64)
        ti.atomic_max(self.acc.most[None], ti.cast(total, ti.f64))
        self.n_pairs[None] = ti.min(total, self.capacity)
        self._geometry(xp)

    @ti.func
    def _geometry(self, xp: ti.template()):
        """Each candidate's contact normal and face spacing at x_n = ``xp``, with the bodies' rotations
        there (``BodyGrid._blended_pair_normal``: an edge particle's faces blended, ``FACE_BLEND``):
        frozen for the step, so a pair's contact term is a smooth function of the positions while
        the solver minimises (a face's choice would jump at edges), and the same for the list
        rebuilt from the same x_n."""
        self._turn_normals(xp)
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            d = xp[i] - xp[j]
            n, s = self._blended_pair_normal(i, j, d, d.norm(), FACE_BLEND)
            self.pnormal[p] = n
            self.pspace[p] = s

    @ti.func
    def _closest(self, a, b):
        """Distance from the origin to the segment {a + t b, t in [0, 1]} [m]."""
        bb = b.dot(b)
        t = ti.cast(0.0, float)
        if bb > 0:
            t = ti.min(ti.max(-a.dot(b) / bb, 0.0), 1.0)
        return (a + t * b).norm()

    @ti.func
    def _find(self, i, rho, start, write: ti.template()):
        """Count particle i's candidates: j > i of another body whose relative path comes within
        S_ij + 2 rho (``_span``: the farthest a pair can touch, a face pair's sqrt(R_ij^2 + s^2));
        with ``write``, store them from slot ``start`` on (those past the capacity are dropped, and
        counted as overflow by the caller)."""
        found = 0
        mi, bi = self.mid[i], self.body[i]
        ci = self._cell_of(mi)
        for o in range(27):  # the 3x3x3 cells around i's (a run-time loop: unrolled it compiles slowly)
            c = ci + ti.Vector([o // 9 - 1, (o // 3) % 3 - 1, o % 3 - 1])
            h = self._bucket(c)
            for k in range(self.bucket_start[h], self.bucket_start[h + 1]):
                j = self.sorted[k]
                # Buckets are shared by distant cells (and two neighbour cells may share one):
                # take j only from the cell it really lies in, so each pair is seen once.
                if j > i and self.body[j] != bi and all(self._cell_of(self.mid[j]) == c):
                    b = self.path[i] - self.path[j]
                    if self._closest(mi - self.mid[j] - 0.5 * b, b) < self._span(i, j) + 2.0 * rho:
                        if ti.static(write):
                            p = start + found
                            if p < self.capacity:
                                self.pa[p] = i
                                self.pb[p] = j
                        found += 1
        return found


@ti.func
def _starts(count: ti.template(), start: ti.template(), size):
    """start[k] = count[0] + ... + count[k-1] for k <= size (one thread: the prefix sum is
    sequential); count is zeroed, to be reused as the fill cursor."""
    for _ in range(1):
        total = 0
        for k in range(size):
            start[k] = total
            total += count[k]
            count[k] = 0
        start[size] = total
