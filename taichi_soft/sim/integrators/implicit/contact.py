"""Terrain contact inside the implicit step: feasible start, active set, multipliers, restitution.

The terrain is an inequality constraint d(x_i) >= 0 (``Terrain.query``). The pieces, each a
per-particle ti.func called from the phases of the step (docs/implicit.md, "Contact"):

* **Feasible start** (``_start_direction``): the step starts on the segment x_n -> predictor, at
  the largest fraction t of it that keeps every particle outside the terrain (the driver then
  halves t until g(x_0) <= g(x_n)). Particles already on the surface whose predictor points
  inward are held from the start and move only along the surface. The predictor is never
  projected: that flattened several layers of the cube at large steps and started the solve far
  above the energy the step began with (docs/implicit.md, "One step, both solvers", item 2).
* **Active set with hysteresis** (``_contact_gradient``): a held particle's normal is filtered
  out of the solve (Baraff & Witkin 1998, Sec. 5.3). It is released only when its multiplier is
  clearly negative, below -m h^2 max(tol, current residual) (an inexact iterate's force error is
  as large as the residual), a margin that grows with each release in the step.
* **Frozen friction**: each held particle's multiplier lam = h^2 |F_n| is frozen for the solve and
  refrozen only by a bounded number of outer updates (``friction_updates``), each of which
  corrects the current objective value, so one objective is minimised between them. A particle
  held from the start that was held at the end of the previous step starts with that step's
  normal force (warm start, the lagged force of IPC); others get theirs at their first gradient.
* **Projection** (``_project``): trial points put held particles back onto the surface (its
  normal may turn along a curved terrain) and project and hold others that end inside.
* **Restitution** (``_bounce``): a held particle that approached faster than the terrain's
  ``bounce_threshold`` leaves with restitution times its approach speed (and, with
  ``impact_friction``, the tangential loss mu |dv_N| of that bounce impulse); slower ones do
  not bounce, as in ``Terrain.impact``. The driver scales all bounces of a step down to the energy
  the step lost, so restitution never adds energy the step did not have.
"""

import taichi as ti

from ...footprint import VEC, per_particle


@ti.data_oriented
class ContactSet:
    """Mixin of ``ImplicitIntegrator``: contact fields and per-particle ti.funcs."""

    # lam_end, not the frozen lam, warm-starts the next step: once a step's refreezes are spent, lam
    # may be an early iterate's over-count (a stiff cube pushed at 1/30 s froze 8x, then 70x its
    # weight into friction and stopped in two steps: bench precision's plausibility table).
    BUFFERS = {
        "normal": per_particle("terrain normal of a held particle", VEC),
        "trial_normal": per_particle("its normal at the line-search trial point", VEC),
        "active": per_particle("1 = held on the terrain surface", ints=True),
        "trial_active": per_particle("held at the line-search trial point", ints=True),
        "released": per_particle("releases in this step (each widens the release margin)", ints=True),
        "lam": per_particle("frozen multiplier h^2 |F_n| of a held particle [kg m]"),
        "lam_end": per_particle("candidate multiplier at the step's last gradient, the normal force the solved "
                                "step took: the next step's warm start (IPC's lagged normal force) [kg m]"),
    }

    def _init_contact(self):
        self.release_tol = ti.field(float, ())  # release margin floor [m/s^2] (the solver's tolerance)

    @ti.func
    def _start_direction(self, i, xi, d, dt):
        """Direction of particle i's start move (predicted move ``d`` = y - x_n, [m]); holds it if it
        sits on the surface and the predictor points inward; lowers ``sc.t_max`` to its crossing fraction.

        A particle held from the start that was held at the end of the previous step starts with the
        previous step's normal force as its friction multiplier (warm start): the first gradient, at
        the predictor, over-counts the load (the predictor compresses the springs above the held
        layer by h^2 g), and refreezing from there cost iterations and friction (docs/implicit.md).
        The previous step's force, h_prev^2 |F_n| (``lam_end``), is rescaled to this step's h^2."""
        warm = ti.cast(0.0, float)
        if self.sc.h2_prev[None] > 0:
            warm = self.lam_end[i] * (dt * dt / self.sc.h2_prev[None])
        self.active[i] = 0
        self.released[i] = 0
        self.lam[i] = 0.0
        self.normal[i] = ti.Vector([0.0, 1.0, 0.0], dt=float)
        dist, nrm = self.terrain.query(i, xi)
        dn = nrm.dot(d)
        if dn < 0:
            if dist <= -0.01 * dn:
                # On the surface (within 1 % of its predicted approach): held from the start, moves
                # along the surface only.
                self.active[i] = 1
                self.normal[i] = nrm
                self.lam[i] = warm
                d -= dn * nrm
            else:
                dist_y, _n = self.terrain.query(i, xi + d)
                if dist_y < 0:
                    ti.atomic_min(self.sc.t_max[None], dist / (dist - dist_y))
        return d

    @ti.func
    def _contact_gradient(self, i, xi, gi, dt):
        """Active set and friction for particle i at xi with (frictionless) gradient gi [kg m].

        Releases a clearly pulling held particle, refreezes its multiplier when the driver asked for
        it (``sc.update``) or when it has none yet (held since the last freeze: it gets its first
        multiplier at its first gradient), corrects the objective for any change of the friction
        weight (the term is linear in lam), and returns gi plus the friction gradient.
        """
        m = self.model
        nrm = self.normal[i]
        lam_old = self.lam[i]
        lam_new = lam_old
        end = ti.cast(0.0, float)  # lam_end: the candidate of a particle still held here
        if self.active[i]:
            c = gi.dot(nrm)  # candidate multiplier: h^2 times the normal force the surface must supply
            # The margin grows with each release in this step (hysteresis against chatter); a
            # pulling particle is never kept held, or its neighbours' multipliers, and with them
            # friction, would carry more than the body's real load.
            margin = m.mass[i] * dt * dt * ti.max(self.release_tol[None], self.sc.res_prev[None]) \
                * (1.0 + 3.0 * self.released[i])
            if c < -margin:
                self.active[i] = 0
                self.released[i] += 1
                lam_new = 0.0
            else:
                cand = ti.max(c, 0.0)
                end = cand
                if self.sc.update[None] or lam_old == 0:
                    lam_new = cand
                self.sc.lam_change[None] += ti.abs(cand - lam_new)
                self.sc.lam_sum[None] += cand
        else:
            lam_new = 0.0
        fh = ti.Matrix.zero(float, 3, 3)
        if lam_new != lam_old or lam_new > 0:
            f0, fg, fh1 = self._friction(i, xi, nrm, 1.0)
            self.sc.f_cur[None] += (lam_new - lam_old) * f0
            gi += lam_new * fg
            fh = lam_new * fh1
        self.lam[i] = lam_new
        self.lam_end[i] = end
        self.fric_hess[i] = fh
        return gi

    @ti.func
    def _project(self, i, xi, moved):
        """Make trial position xi of particle i feasible (if ``moved``); writes x_trial, trial_active,
        trial_normal."""
        hit = self.active[i]
        nrm = self.normal[i]
        if self._free(i) and moved:
            dist, nq = self.terrain.query(i, xi)
            if hit or dist < 0:
                xi -= dist * nq
                hit = 1
                nrm = nq
        self.x_trial[i] = xi
        self.trial_active[i] = hit
        self.trial_normal[i] = nrm
        return xi

    @ti.func
    def _bounce(self, i, vi, xi):
        """Velocity change [m/s] restitution asks for particle i at xi with solved velocity vi: a
        held particle, or one the step left inside the terrain's skin (``epsilon``) approaching
        faster than the bounce threshold.

        A held particle approached with its velocity at the start of the step (its solved normal
        velocity is about 0); below the bounce threshold it keeps what the solve gave it. A skin
        particle approaches with its solved velocity; it is held for the restitution solve, so the
        springs carry its impact to the body. (``Terrain.respond`` reflected it alone, and a stiff
        body swallowed that: the flat x1000 drop bounced at some steps and not at others, issue 22.)
        Slower skin particles are left to ``respond``'s local stop: stopping them through the body
        too moved the converged tilted-plane slide 1.6 cm away from the explicit reference at
        0.1 ms (tests/test_consistency.py), where the local stop keeps it within 6.4 mm."""
        t = self.terrain
        delta = ti.Vector.zero(float, 3)
        skin = 0
        if not self.active[i] and self._free(i):
            dist, nq = t.query(i, xi)
            if dist < t.epsilon[None] and -nq.dot(vi) > t.bounce_threshold[None]:
                skin = 1
                self.active[i] = 1
                self.normal[i] = nq
        if self.active[i] and self._free(i):
            nrm = self.normal[i]
            vn = nrm.dot(vi)
            approach = nrm.dot(self.v_prev[i])
            if skin:
                approach = vn
            if -approach > t.bounce_threshold[None]:
                target = -t.restitution[None] * approach
                if target > vn:
                    dvn = target - vn
                    vt = vi - vn * nrm
                    vt_new = vt
                    if t.impact_friction[None]:
                        # The absorbing part of the impact impulse met friction inside the solve;
                        # the bounce impulse m dvn meets it here (Coulomb, never reversing).
                        sl = vt.norm()
                        if sl > 0:
                            vt_new = vt * ti.max(0.0, 1.0 - t.friction[None] * dvn / sl)
                    delta = (vt_new - vt) + dvn * nrm
        return delta

    @ti.func
    def _bounce_scale(self, budget):
        """Largest s in [0, 1] with sum 1/2 m |v + s dv|^2 - 1/2 m |v|^2 = A s^2 + B s <= budget [J]."""
        a = self.sc.bounce_a[None]
        b = self.sc.bounce_b[None]
        s = ti.cast(1.0, float)
        if a > 0 and a + b > budget:
            disc = b * b + 4.0 * a * budget
            s = 0.0
            if disc >= 0:
                s = ti.min(1.0, ti.max(0.0, (-b + ti.sqrt(disc)) / (2.0 * a)))
            self.sc.bounce_limited[None] = 1
        return s
