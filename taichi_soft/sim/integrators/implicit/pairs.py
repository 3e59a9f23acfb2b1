"""Body-body contact inside the implicit step: pairs, penalty, friction, restitution.

Only an implicit integrator of a scene with several bodies builds a ``PairContacts`` (a one-body
scene compiles none of this). Particles are spheres of radius half their body's lattice spacing
(``collision.contact_radii``, as for the explicit methods); a pair (i, j) of particles of
different bodies overlaps by o = R_ij - |x_i - x_j|, R_ij = r_i + r_j. Per step
(docs/implicit.md, "Contact between bodies"):

* **Pairs** (``begin``, ``follow``; pair_list.py): the candidate pairs are those whose relative
  path along the step's segments comes within R_ij + R_max / 2 of contact, found through a
  spatial hash of the particles near another body's box; the list is built along the start paths
  and rebuilt when a search direction would leave the tube it is complete for (a trial outside is
  rejected, counted), so a pair outside the list cannot touch anywhere the solver looks.
* **Feasible start**: the start fraction t of the predicted move is lowered to the first contact
  of any candidate pair (the terrain's feasible start, extended to pairs).
* **Contact in the objective**: a stiff penalty kappa m_ij / 2 o^2 [kg m^2] per overlapping pair
  (m_ij the reduced mass, kappa ``contact_stiffness``), i.e. a pair potential of stiffness
  kappa m_ij / h^2 [N/m]: a minimiser stops an approach of o_pred (the overlap the free motion
  would make) at about o_pred / (1 + kappa). Its gradient acts on both particles equal and
  opposite, so momentum between bodies is exchanged exactly. Hessian block kappa m_ij n n^T (the
  transverse part, negative under overlap, clamped to 0 as for a compressed spring).
* **Coulomb friction between bodies**: the terrain's lagged friction (IPC) on the relative
  tangential displacement of a pair, mu lam f0(|u_t|), its multiplier lam = kappa m_ij o (h^2 |F_n|)
  and normal frozen for the solve and refrozen with the terrain's (``sc.update``); a pair that
  separates is released at once. Equal and opposite like the normal force.
* **Restitution** (``end``): a pair in contact at the end whose approach at the start was faster
  than the bounce threshold gets a relative normal velocity of restitution times its approach,
  as an impulse split by inverse mass (equal and opposite), relaxed by the contact count of its
  busier particle; the driver scales all bounces of a step to the energy the step lost.
"""

import taichi as ti

from .objective import lagged_friction
from .pair_list import PAIRS_PER_PARTICLE, PairList, field_bytes
from .scalars import PAIR_ACCOUNTS, accounts, read_accounts

__all__ = ["PairContacts", "PAIRS_PER_PARTICLE", "field_bytes"]


@ti.data_oriented
class PairContacts(PairList):
    """Contact between the bodies of ``owner.model`` inside ``owner``'s step (an ImplicitIntegrator)."""

    def __init__(self, owner, stiffness: float):
        model = owner.model
        n = model.n_particles
        self.owner = owner
        self.model = model
        self.terrain = owner.terrain
        self._init_list(owner, model)
        vec = lambda size: ti.Vector.field(3, float, size)  # noqa: E731
        self.kappa = ti.field(float, ())  # penalty stiffness [-], times m_ij / h^2 [N/m]
        self.kappa[None] = stiffness
        self.block = ti.Matrix.field(3, 3, float, self.capacity)  # pair Hessian block [kg]
        self.grad = vec(n)  # pair terms' gradient per particle [kg m]
        self.hess = ti.Matrix.field(3, 3, float, n)  # their diagonal Hessian blocks [kg]
        self.dv = vec(n)  # restitution velocity change [m/s]
        self.touch = ti.field(ti.i32, n)  # pairs in contact at the end of the step
        self.acc = accounts(PAIR_ACCOUNTS)

    def stats(self, steps: float) -> dict:
        """Counters for the run summary since the last call: pairs in contact at the end of a step
        (per step), overlap the predictor would have made and the step removed [m, summed over
        pairs and steps], the deepest overlap at the end of any step [m], candidate pairs per step
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
        }

    def reset(self):
        self.acc.fill(0)

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
    def begin(self, xp: ti.template(), yd: ti.template(), d: ti.template(), u0: ti.template()):
        """Candidate pairs for the tube around the start paths x_n + u0 + t d (x_n = ``xp``; u0 the
        pinned particles' fixed move; pair_list.py); lowers the owner's start fraction ``sc.t_max`` to the
        first contact along them. ``yd`` = y - x_n (the predicted move) is for the removed-overlap
        counter."""
        for i in range(self.n):
            self.base[i] = u0[i]
            self.path[i] = d[i]
        self._collect(xp)
        self.acc.pairs[None] += ti.cast(self.n_pairs[None], ti.f64)
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            self.lam[p] = 0.0
            r = self._reach(i, j)
            a = (xp[i] + u0[i]) - (xp[j] + u0[j])
            self.acc.removed[None] += ti.cast(ti.max(r - (xp[i] - xp[j] + yd[i] - yd[j]).norm(), 0.0), ti.f64)
            b = d[i] - d[j]
            # First t in (0, 1] with |a + t b| = r, for a pair apart at x_n.
            bb = b.dot(b)
            ab = a.dot(b)
            cc = a.dot(a) - r * r
            if cc > 0 and bb > 0 and ab < 0:
                disc = ab * ab - bb * cc
                if disc > 0:
                    t = (-ab - ti.sqrt(disc)) / bb
                    if t < 1.0:
                        ti.atomic_min(self.owner.sc.t_max[None], ti.max(t, 0.0))

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
        return lagged_friction(disp[i] - disp[j], nrm, self.terrain.friction[None] * lam, self.owner.fric_eps[None])

    @ti.func
    def _normal(self, p, d, dist):
        nrm = self.fnormal[p]
        if dist > 0:
            nrm = d / dist
        return nrm

    @ti.func
    def gradient(self, x: ti.template(), disp: ti.template()):
        """Per-particle gradient (``grad``) and diagonal Hessian blocks (``hess``) of the pair terms
        at positions x (displacements ``disp`` = x - x_n), the pair blocks for ``apply``; freezes,
        refreezes (``sc.update``) and releases friction multipliers, correcting the objective value
        as the terrain's do. Adds the pairs in contact to ``sc.n_active`` and their candidate
        multipliers to the refreeze test's sums."""
        for i in range(self.n):
            self.grad[i] = ti.Vector.zero(float, 3)
            self.hess[i] = ti.Matrix.zero(float, 3, 3)
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            d = x[i] - x[j]
            dist = d.norm()
            ov = self._reach(i, j) - dist
            kp = self._stiffness(i, j)
            nrm = self._normal(p, d, dist)
            g = ti.Vector.zero(float, 3)
            hb = ti.Matrix.zero(float, 3, 3)
            lam_old = self.lam[p]
            lam_new = lam_old
            n_old = self.fnormal[p]
            refrozen = 0
            if ov > 0:
                g = -(kp * ov) * nrm
                hb = kp * nrm.outer_product(nrm)
                self.owner.sc.n_active[None] += 1.0
                self.owner.sc.n_pairs[None] += 1.0
                cand = kp * ov
                if self.owner.sc.update[None] or lam_old == 0:
                    lam_new = cand
                    self.fnormal[p] = nrm
                    refrozen = 1
                self.owner.sc.lam_change[None] += ti.abs(cand - lam_new)
                self.owner.sc.lam_sum[None] += cand
            else:
                lam_new = 0.0  # apart: released at once
            changed = refrozen or lam_new != lam_old
            if changed and lam_old > 0:  # the objective's friction term changes from lam_old f0(n_old) ...
                f_old, _g, _h = self._friction(p, disp, n_old, lam_old)
                self.owner.sc.f_cur[None] -= f_old
            if lam_new > 0:  # ... to lam_new f0(n_new)
                f_new, fg, fh = self._friction(p, disp, self.fnormal[p], lam_new)
                if changed:
                    self.owner.sc.f_cur[None] += f_new
                g += fg
                hb += fh
            self.lam[p] = lam_new
            self.block[p] = hb
            self.grad[i] += g
            self.grad[j] -= g
            self.hess[i] += hb
            self.hess[j] += hb

    @ti.func
    def apply(self, src: ti.template(), dst: ti.template()):
        """Add the pair blocks' off-diagonal part to dst = H src (the diagonal is in the owner's
        per-particle contact blocks), filtered as the owner filters its rows."""
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            hb = self.block[p]
            dst[i] -= self.owner._filter(i, hb @ src[j])
            dst[j] -= self.owner._filter(j, hb @ src[i])

    @ti.func
    def trial_end(self, xt: ti.template(), ut: ti.template(), dt):
        """Add the pair terms at the trial point xt (displacements ut) to ``sc.f_trial`` (penalty and
        frozen friction) and the penalty's energy [J] to ``sc.e_trial``; a trial outside the tube
        (pair_list.py) gets an infinite value."""
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            ov = self._reach(i, j) - (xt[i] - xt[j]).norm()
            if ov > 0:
                e = 0.5 * self._stiffness(i, j) * ov * ov
                self.owner.sc.f_trial[None] += e
                self.owner.sc.e_trial[None] += e / (dt * dt)
            if self.lam[p] > 0:
                fe, _g, _h = self._friction(p, ut, self.fnormal[p], self.lam[p])
                self.owner.sc.f_trial[None] += fe
        if self.outside():
            self.owner.sc.f_trial[None] = 1e300
            self.acc.trust[None] += 1.0

    # -- end: restitution and counters ------------------------------------------------------------
    @ti.func
    def end(self, x: ti.template(), dt):
        """Restitution velocity changes ``dv`` for the pairs in contact at the end of the step, and
        the step's counters."""
        t = self.terrain
        for i in range(self.n):
            self.dv[i] = ti.Vector.zero(float, 3)
            self.touch[i] = 0
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            ov = self._reach(i, j) - (x[i] - x[j]).norm()
            if ov > 0:
                self.touch[i] += 1
                self.touch[j] += 1
                self.acc.contact[None] += 1.0
                self.acc.removed[None] -= ti.cast(ov, ti.f64)
                ti.atomic_max(self.acc.deepest[None], ti.cast(ov, ti.f64))
        for p in range(self.n_pairs[None]):
            i, j = self.pa[p], self.pb[p]
            d = x[i] - x[j]
            dist = d.norm()
            if self._reach(i, j) - dist > 0 and dist > 0:
                nrm = d / dist
                approach = nrm.dot(self.owner.v_prev[i] - self.owner.v_prev[j])
                if -approach > t.bounce_threshold[None]:
                    vn = nrm.dot(self.owner.u[i] - self.owner.u[j]) / dt
                    target = -t.restitution[None] * approach
                    if target > vn:
                        inv_i, inv_j = self.model.inv_mass[i], self.model.inv_mass[j]
                        share = (target - vn) / ti.max(inv_i + inv_j, 1e-30) / ti.cast(
                            ti.max(self.touch[i], self.touch[j]), float)
                        self.dv[i] += (share * inv_i) * nrm
                        self.dv[j] -= (share * inv_j) * nrm
                        self.acc.bounces[None] += 1.0
