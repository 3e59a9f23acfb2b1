"""Body-body contact inside the implicit step: pairs, penalty, friction, restitution.

Only an implicit integrator of a scene with several bodies builds a ``PairContacts`` (a one-body
scene compiles none of this). A pair (i, j) of particles of different bodies has the explicit
methods' geometry (``contact.bodies``): on a face, a normal n from the bodies' face normals and the
overlap o = R_ij - n . (x_i - x_j) along it, weighted by w = (1 - |t|^2 / s^2)^2 of the tangential
offset t within the face spacing s, so that faces are flat; otherwise spheres, o = R_ij - |x_i - x_j|,
w = 1. In contact when o > 0 and w > 0. One difference: an edge or corner particle's face normal is
its faces' normals blended by how well each faces the other particle (``pair_list.FACE_BLEND``),
where the explicit methods take the best-facing face. Per step (docs/implicit.md, "Contact between
bodies"):

* **Pairs** (``begin``, ``follow``; pair_list.py): the candidate pairs are those whose relative
  path along the step's segments comes within S_ij + R_max / 2 of the pair's farthest contact S_ij,
  found through a spatial hash of the particles near another body's box; the list is built along
  the start paths and rebuilt when a search direction would leave the tube it is complete for (a
  trial outside is rejected, counted), so a pair outside the list cannot touch anywhere the solver
  looks. Each pair's normal and face are **frozen at x_n** for the step (with the bodies' best-fit
  rotations there): the pair's term is then a smooth function of the positions, where a face chosen
  anew at each iterate would jump at edges.
* **Feasible start**: the start fraction t of the predicted move is lowered to the first contact
  of any candidate pair (the terrain's feasible start, extended to pairs).
* **Contact in the objective**: a stiff penalty w kappa m_ij / 2 o^2 [kg m^2] per pair in contact
  (m_ij the reduced mass, kappa ``contact_stiffness``), i.e. a pair potential of stiffness
  kappa m_ij / h^2 [N/m]: a minimiser stops an approach of o_pred (the overlap the free motion
  would make) at about o_pred / (1 + kappa). Its gradient (with the weight's) acts on both particles
  equal and opposite, so momentum between bodies is exchanged exactly. Hessian block
  w kappa m_ij n n^T (the weight's and, for spheres, the transverse parts left out: positive
  semi-definite, as for a compressed spring).
* **Coulomb friction between bodies**: the terrain's lagged friction (IPC) on the relative
  tangential displacement of a pair, mu lam f0(|u_t|), its multiplier lam = h^2 |F_n| and normal
  frozen at x_n from the load the pair carried at the end of the last step and kept for the whole
  solve (also where an iterate lifts the pair apart): a pair that comes into contact in a step
  gets its friction from the next step on.
* **Restitution** (``end``): a pair in contact at the end whose approach at the start was faster
  than the bounce threshold gets a relative normal velocity of restitution times its approach,
  as an impulse split by inverse mass (equal and opposite), relaxed by the contact count of its
  busier particle; the driver scales all bounces of a step to the energy the step lost.
* **Energy account**: freezing a pair's geometry at x_n changes its penalty energy between one
  step's end and the next step's start; ``begin`` counts that change (``body_pair_energy_refrozen_J``).
  An energy balance (bench energy, the tests) adds the penalty the last step ended with
  (``energy_terms``) and takes nothing off: the steps dissipate what refreezing adds (the blended
  normals cut it 4-5x on the pile; docs/benchmarks/ENERGY.md).
"""

import taichi as ti

from .objective import lagged_friction
from .pair_list import PAIRS_PER_PARTICLE, PairList, field_bytes
from .scalars import PAIR_ACCOUNTS, accounts, read_accounts, zero_accounts

__all__ = ["PairContacts", "PAIRS_PER_PARTICLE", "field_bytes"]


@ti.data_oriented
class PairContacts(PairList):
    """Contact between the bodies of ``model`` inside an implicit step: a part of ``ImplicitIntegrator``.

    Given at construction: the ``model``, the ``terrain``, the step's scalars ``sc`` (it reads
    h2_prev; it lowers t_max and writes n_active, n_pairs and, in the trial, f_trial and e_trial), the
    ``objective`` (the step's start x_n, v_n, its iterate u and direction dx, h^2, the friction
    length, the rows' filter) and the penalty ``stiffness`` kappa [-]. Nothing of the solver.
    """

    def __init__(self, model, terrain, sc, objective, stiffness: float):
        n = model.n_particles
        self.model, self.terrain, self.sc, self.objective = model, terrain, sc, objective
        self._init_list(model)
        vec = lambda size: ti.Vector.field(3, float, size)  # noqa: E731
        self.kappa = ti.field(float, ())  # penalty stiffness [-], times m_ij / h^2 [N/m]
        self.kappa[None] = stiffness
        self.block = ti.Matrix.field(3, 3, float, self.capacity)  # pair Hessian block [kg]
        self.grad = vec(n)  # pair terms' gradient per particle [kg m]
        self.hess = ti.Matrix.field(3, 3, float, n)  # their diagonal Hessian blocks [kg]
        self.dv = vec(n)  # restitution velocity change [m/s]
        self.touch = ti.field(ti.i32, n)  # pairs in contact at the end of the step
        self.weight = ti.field(float, n)  # the sum of their weights w
        self.depth = ti.field(float, n)  # the sum of their w o [m]
        self.e_end = ti.field(ti.f64, ())  # penalty energy at the end of the last step [J]
        self.acc = accounts(PAIR_ACCOUNTS)

    def stats(self, steps: float) -> dict:
        """Counters for the run summary since the last call: pairs in contact at the end of a step
        (per step), overlap (w o) the predictor would have made and the step removed [m, summed over
        pairs and steps], the deepest particle in another body at the end of any step [m] (the
        weighted mean overlap of its pairs, ``end``), candidate pairs per step
        and the most in one list, lists rebuilt for a search direction (per step), restitution
        bounces, list overflows and trials outside the tube (pair_list.py)."""
        a = read_accounts(self.acc)
        return {
            "body_pairs_in_contact_per_step": a["contact"] / steps,
            "body_overlap_removed_m": a["removed"],
            "body_deepest_overlap_m": a["deepest"],
            "body_candidate_pairs_per_step": a["pairs"] / steps,
            "body_candidate_pairs_most": int(a["most"]),
            "body_pair_lists_rebuilt_per_step": a["gathers"] / steps,
            "body_bounces": int(a["bounces"]),
            "body_pair_overflows": int(a["overflow"]),
            "body_trust_region_rejections": int(a["trust"]),
            "body_pair_energy_refrozen_J": a["refrozen"],
        }

    def energy_terms(self) -> tuple[float, float]:
        """(penalty energy at the end of the last step [J], energy counted as refrozen since the
        last ``stats()`` [J]): what an energy balance adds to the bodies' own energy, and what the
        steps' refrozen geometry changed of it (module doc)."""
        return float(self.e_end[None]), float(self.acc.refrozen[None])

    def reset(self):
        zero_accounts(self.acc)
        self.e_end[None] = 0.0
        self.n_pairs[None] = 0  # no pair carries a load into the next step

    # -- geometry -------------------------------------------------------------------------------
    @ti.func
    def _reach(self, i, j):
        return self.radius[i] + self.radius[j]

    @ti.func
    def _stiffness(self, i, j):
        """kappa m_ij [kg], m_ij the reduced mass (a pinned end: the free one's mass)."""
        inv = self.model.inv_mass[i] + self.model.inv_mass[j]
        return self.kappa[None] / ti.max(inv, 1e-30)

    # -- begin: candidate pairs, feasible start ---------------------------------------------------
    @ti.func
    def begin(self, xp: ti.template(), yd: ti.template(), d: ti.template(), u0: ti.template(), dt):
        """Candidate pairs for the tube around the start paths x_n + u0 + t d (x_n = ``xp``; u0 the
        pinned particles' fixed move; pair_list.py) and their geometry frozen at x_n; lowers the
        step's start fraction ``sc.t_max`` to the first contact along them. ``yd`` = y - x_n (the
        predicted move) is for the removed-overlap counter; ``dt`` [s] the step, for the energy
        counted as refrozen."""
        # Friction's multipliers and normals (IPC's lag): the load each pair carried at the end of
        # the last step (``end`` left it in ``lam``), with that step's geometry -- re-evaluated with
        # this step's, a tilt of the frozen normal by 1e-4 rad shifts a face pair's overlap (a few
        # um at rest) by 1e-4 |t|, tens of um, and friction swung between 0 and 5 mu m g. The
        # penalty force is kappa m_ij w o / h^2 with the last step's h; lam = h^2 |F_n|.
        self._stash()
        for i in range(self.n):
            self.base[i] = u0[i]
            self.path[i] = d[i]
        self._collect(xp)
        load = ti.cast(1.0, float)
        if self.sc.h2_prev[None] > 0:
            load = self.objective.h2[None] / self.sc.h2_prev[None]
        self._restore(load)
        self.acc.pairs[None] += ti.cast(self.n_pairs[None], ti.f64)
        # The penalty energy at x_n with this step's geometry, less what the last step ended with.
        self.acc.refrozen[None] -= self.e_end[None]
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            o, w, _n = self._gap(p, xp[i] - xp[j])
            if o > 0 and w > 0:
                self.acc.refrozen[None] += ti.cast(self._energy(p, o, w) / (dt * dt), ti.f64)
            o, w, _n = self._gap(p, xp[i] - xp[j] + yd[i] - yd[j])
            if w > 0:
                self.acc.removed[None] += ti.cast(w * ti.max(o, 0.0), ti.f64)
            a = (xp[i] + u0[i]) - (xp[j] + u0[j])
            t = self._first_contact(p, a, d[i] - d[j])
            if t < 1.0:
                ti.atomic_min(self.sc.t_max[None], ti.max(t, 0.0))

    @ti.func
    def follow(self):
        """After a search direction (serial driver): rebuild the list if the line search could leave
        the tube (pair_list.py)."""
        self.check()
        if self.again[None]:
            self.regather()

    # -- the objective --------------------------------------------------------------------------
    @ti.func
    def _friction(self, p, disp: ti.template(), nrm, lam):
        """Friction of pair p at displacements ``disp`` = x - x_n: (energy [kg m^2], gradient w.r.t.
        x_i [kg m], Hessian block [kg]); the terrain's Huber-smoothed lagged friction on the relative
        tangential displacement."""
        i, j = self.pa[p], self.pb[p]
        return lagged_friction(disp[i] - disp[j], nrm, self.terrain.friction[None] * lam,
                               self.objective.fric_eps[None])

    @ti.func
    def _gap(self, p, d):
        """(overlap o [m], weight w, unit normal n from j toward i) of pair p at d = x_i - x_j: the
        explicit methods' geometry (``contact.bodies.BodyGrid._pair_gap``) with the normal and face frozen
        at x_n (``_geometry``); a pair of spheres' normal follows d (the frozen friction normal if
        d = 0). In contact when o > 0 and w > 0; w = 0 beyond the pair's span, as there."""
        i, j = self.pa[p], self.pb[p]
        dist = d.norm()
        s = self.pspace[p]
        n = self.pnormal[p]
        if s == 0:
            n = self.fnormal[p]
            if dist > 0:
                n = d / dist
        o, w = self._pair_gap(i, j, d, dist, n, s)
        if dist >= self._span(i, j):
            w = 0.0
        return o, w, n

    @ti.func
    def _weight_gradient(self, p, d, n, c):
        """c / 2 times the gradient of pair p's weight w with respect to x_i at d = x_i - x_j, normal
        n (c = kappa m_ij o^2: the weight's part of the penalty's gradient); 0 for spheres.
        w = (1 - |t|^2 / s^2)^2 of the tangential offset t = d - (n . d) n."""
        g = ti.Vector.zero(float, 3)
        s = self.pspace[p]
        if s > 0:
            t = d - n.dot(d) * n
            q = ti.max(1.0 - t.norm_sqr() / (s * s), 0.0)
            g = (-2.0 * c * q / (s * s)) * t
        return g

    @ti.func
    def _energy(self, p, o, w):
        """The penalty w kappa m_ij / 2 o^2 [kg m^2] of pair p in contact (o > 0, w > 0)."""
        return 0.5 * w * self._stiffness(self.pa[p], self.pb[p]) * o * o

    @ti.func
    def _first_contact(self, p, a, b):
        """The first t in [0, 1) at which pair p, apart at relative position a [m] and moving by
        t b, comes into contact (2.0: none): spheres where |a + t b| = R_ij; on a face where
        n . (a + t b) = R_ij, if the weight there is positive."""
        i, j = self.pa[p], self.pb[p]
        r = self._reach(i, j)
        t = ti.cast(2.0, float)
        if self.pspace[p] == 0:
            bb = b.dot(b)
            ab = a.dot(b)
            cc = a.dot(a) - r * r
            if cc > 0 and bb > 0 and ab < 0:
                disc = ab * ab - bb * cc
                if disc > 0:
                    t = (-ab - ti.sqrt(disc)) / bb
        else:
            n = self.pnormal[p]
            na, nb = n.dot(a), n.dot(b)
            if na > r and nb < 0:
                tc = (na - r) / -nb
                _o, w, _n = self._gap(p, a + tc * b)
                if w > 0:
                    t = tc
        return t

    @ti.func
    def gradient(self, x: ti.template(), disp: ti.template()):
        """Per-particle gradient (``grad``) and diagonal Hessian blocks (``hess``) of the pair terms
        at positions x (displacements ``disp`` = x - x_n), and the pair blocks for ``apply``. Adds
        the pairs in contact to ``sc.n_active``.

        Friction's multipliers stay as ``begin`` froze them, at x_n, for the whole solve (IPC's
        lag), also where an iterate lifts a pair apart. (Frozen anew where a pair touched inside
        the solve, or refrozen to an unconverged iterate's overlaps, which are not the load, a
        slide's friction swung from 0 to 2 mu m g between steps, and refreezing after convergence
        left the Newton iterations capped short of it: bench contact gave 3.8-4.1 m/s^2 against
        mu g = 2.94.)"""
        for i in range(self.n):
            self.grad[i] = ti.Vector.zero(float, 3)
            self.hess[i] = ti.Matrix.zero(float, 3, 3)
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            d = x[i] - x[j]
            ov, w, nrm = self._gap(p, d)
            kp = self._stiffness(i, j)
            g = ti.Vector.zero(float, 3)
            hb = ti.Matrix.zero(float, 3, 3)
            if ov > 0 and w > 0:
                g = -(kp * w * ov) * nrm + self._weight_gradient(p, d, nrm, kp * ov * ov)
                hb = (kp * w) * nrm.outer_product(nrm)
                self.sc.n_active[None] += 1.0
                self.sc.n_pairs[None] += 1.0
            if self.lam[p] > 0:
                _f, fg, fh = self._friction(p, disp, self.fnormal[p], self.lam[p])
                g += fg
                hb += fh
            self.block[p] = hb
            self.grad[i] += g
            self.grad[j] -= g
            self.hess[i] += hb
            self.hess[j] += hb

    @ti.func
    def apply(self, src: ti.template(), dst: ti.template()):
        """Add the pair blocks' off-diagonal part to dst = H src (the diagonal is in the objective's
        per-particle contact blocks), filtered as the objective filters its rows."""
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            hb = self.block[p]
            dst[i] -= self.objective.filter(i, hb @ src[j])
            dst[j] -= self.objective.filter(j, hb @ src[i])

    @ti.func
    def trial_end(self, xt: ti.template(), ut: ti.template(), dt):
        """Add the pair terms at the trial point xt (displacements ut) to ``sc.f_trial`` (penalty and
        frozen friction) and the penalty's energy [J] to ``sc.e_trial``; a trial outside the tube
        (pair_list.py) gets an infinite value."""
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            ov, w, _n = self._gap(p, xt[i] - xt[j])
            if ov > 0 and w > 0:
                e = self._energy(p, ov, w)
                self.sc.f_trial[None] += e
                self.sc.e_trial[None] += e / (dt * dt)
            if self.lam[p] > 0:
                fe, _g, _h = self._friction(p, ut, self.fnormal[p], self.lam[p])
                self.sc.f_trial[None] += fe
        if self.outside():
            self.sc.f_trial[None] = 1e300
            self.acc.trust[None] += 1.0

    # -- end: restitution and counters ------------------------------------------------------------
    @ti.func
    def end(self, x: ti.template(), dt):
        """Restitution velocity changes ``dv`` for the pairs in contact at the end of the step, the
        penalty energy the step ends with (``e_end`` [J], h = ``dt``), each pair's load for the next
        step's friction (``lam``, ``fnormal``; ``begin``) and the step's counters."""
        t = self.terrain
        for i in range(self.n):
            self.dv[i] = ti.Vector.zero(float, 3)
            self.touch[i] = 0
            self.weight[i] = 0.0
            self.depth[i] = 0.0
        self.e_end[None] = 0.0
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            ov, w, nrm = self._gap(p, x[i] - x[j])
            self.lam[p] = 0.0  # the solve is over: now the load for the next step's friction
            if ov > 0 and w > 0:
                self.lam[p] = self._stiffness(i, j) * w * ov
                self.fnormal[p] = nrm
                self.touch[i] += 1
                self.touch[j] += 1
                self.weight[i] += w
                self.weight[j] += w
                self.depth[i] += w * ov
                self.depth[j] += w * ov
                self.acc.contact[None] += 1.0
                self.acc.removed[None] -= ti.cast(w * ov, ti.f64)
                self.e_end[None] += ti.cast(self._energy(p, ov, w) / (dt * dt), ti.f64)
        # A particle's depth in another body: the weighted mean overlap of its pairs, relaxed as
        # the explicit pass relaxes its corrections (over a face the weights sum to 1-1.125; a
        # pair at the rim of its weight, w near 0, measures its overlap from a plane that extends
        # past the face's particles, tenths of a spacing where no body is).
        for i in range(self.n):
            if self.weight[i] > 0:
                ti.atomic_max(self.acc.deepest[None], ti.cast(self.depth[i] / ti.max(self.weight[i], 1.0), ti.f64))
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            ov, w, nrm = self._gap(p, x[i] - x[j])
            if ov > 0 and w > 0:
                approach = nrm.dot(self.objective.v_prev[i] - self.objective.v_prev[j])
                if -approach > t.bounce_threshold[None]:
                    vn = nrm.dot(self.objective.u[i] - self.objective.u[j]) / dt
                    target = -t.restitution[None] * approach
                    if target > vn:
                        inv_i, inv_j = self.model.inv_mass[i], self.model.inv_mass[j]
                        share = (target - vn) / ti.max(inv_i + inv_j, 1e-30) / ti.cast(
                            ti.max(self.touch[i], self.touch[j]), float)
                        self.dv[i] += (share * inv_i) * nrm
                        self.dv[j] -= (share * inv_j) * nrm
                        self.acc.bounces[None] += 1.0
