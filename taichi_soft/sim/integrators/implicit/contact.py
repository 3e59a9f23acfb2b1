"""Terrain contact inside the implicit step: feasible start, active set, multipliers, restitution.

The terrain is an inequality constraint d(x_i) >= 0 (``Terrain.query``). ``TerrainContact`` is a
part of the step (the driver holds it as ``contact``); its pieces, each a per-particle ti.func
called from the phases of the step (docs/implicit.md, "Contact"):

* **Feasible start** (``start``): the step starts on the segment x_n -> predictor, at
  the largest fraction t of it that keeps every particle outside the terrain (the driver then
  halves t until g(x_0) <= g(x_n)). Particles already on the surface whose predictor points
  inward are held from the start and move only along the surface. The predictor is never
  projected: that flattened several layers of the cube at large steps and started the solve far
  above the energy the step began with (docs/implicit.md, "One step, both solvers", item 2).
* **Active set with hysteresis** (``gradient``): a held particle's normal is filtered
  out of the solve (Baraff & Witkin 1998, Sec. 5.3). It is released only when its multiplier is
  clearly negative, below -m h^2 max(tol, current residual) (an inexact iterate's force error is
  as large as the residual), a margin that grows with each release in the step.
* **Frozen friction**: each held particle's multiplier lam = h^2 |F_n| is frozen for the solve and
  refrozen only by a bounded number of outer updates (``friction_updates``), each of which
  corrects the current objective value, so one objective is minimised between them. A particle
  held from the start that was held at the end of the previous step starts with that step's
  normal force (warm start, the lagged force of IPC); others get theirs at their first gradient.
* **Projection** (``project``): trial points put held particles back onto the surface (its
  normal may turn along a curved terrain) and project and hold others that end inside.
* **Restitution** (``bounce``): a held particle that approached faster than the terrain's
  ``bounce_threshold`` leaves with restitution times its approach speed (and, with
  ``impact_friction``, the tangential loss mu |dv_N| of that bounce impulse); slower ones do
  not bounce, as in ``Terrain.impact``. The driver scales all bounces of a step down to the energy
  the step lost, so restitution never adds energy the step did not have.
"""

import taichi as ti

from ...allocation import allocate
from ...footprint import VEC, per_particle
from .objective import lagged_friction


@ti.data_oriented
class TerrainContact:
    """The terrain's contact set of an implicit step: a part of ``ImplicitIntegrator``.

    Inputs, given at construction: the ``model`` (masses, pinned particles), the ``terrain``
    (``query``, restitution, friction) and the step's scalars ``sc`` (scalars.py: it reads
    ``h2_prev``, ``res_prev`` and ``update``; it writes ``t_max``, ``lam_change``, ``lam_sum`` and
    ``f_cur``); per call, the particle's position and its displacement from the step's base
    (x - x_n - u_base, what friction measures) and the friction length ``eps`` [m].

    Outputs: ``active[i]`` (1: held on the surface) and ``normal[i]`` (its surface normal), which the
    driver's filter, the restitution spread and the residual read; the friction Hessian block
    ``gradient`` returns; the projected trial position ``project`` returns. Everything else is its own.
    """

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

    def __init__(self, model, terrain, sc):
        """Allocates the fields only (no write: the owner's pending SNode tree stays open)."""
        self.model = model
        self.terrain = terrain
        self.sc = sc
        allocate(self, self.BUFFERS, model.n_particles, 0)
        self.release_tol = ti.field(float, ())  # release margin floor [m/s^2] (the solver's tolerance)

    def reset(self):
        """No held particle carries a force into the next step (a reset state has no history)."""
        self._clear_loads()

    @ti.kernel
    def _clear_loads(self):
        # one kernel, not a ``fill`` (a compile) per field
        for i in self.lam:
            self.lam[i] = 0.0
            self.lam_end[i] = 0.0

    @ti.func
    def _friction(self, disp, nrm, lam, eps):
        """Friction term of a held particle displaced ``disp`` from the step's base: (energy
        [kg m^2], gradient [kg m], Hessian [kg]).

        mu lam f0(|u_t|), u_t the tangential part of ``disp``, f0 the Huber function (|u_t| beyond
        ``eps`` = friction_velocity * h, quadratic below): the gradient is mu lam u_t/|u_t|,
        Coulomb's bound mu |F_n| times h^2. Beyond eps the Hessian is that of the quadratic majorant
        c |u|^2 / (2 |u_t|) + c |u_t| / 2 (iteratively reweighted least squares): a Newton step then
        never carries the particle past the point where friction stops it, which the exact Hessian,
        with no curvature along u_t, would; it is PSD and continuous at eps.
        """
        return lagged_friction(disp, nrm, self.terrain.friction[None] * lam, eps)

    @ti.func
    def release(self, i):
        """Particle i is pinned: never held, no multiplier."""
        self.active[i] = 0
        self.lam[i] = 0.0
        self.lam_end[i] = 0.0

    @ti.func
    def start(self, i, xi, d, dt):
        """Direction of particle i's start move (predicted move ``d`` = y - x_n, [m]); holds it if it
        sits on the surface and the predictor points inward; lowers ``sc.t_max`` to its crossing fraction.

        A particle held from the start that was held at the end of the previous step starts with the
        previous step's normal force as its friction multiplier (warm start): the first gradient, at
        the predictor, over-counts the load (the predictor compresses the springs above the held
        layer by h^2 g), and refreezing from there cost iterations and friction (docs/benchmarks/IMPLICIT.md).
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
    def gradient(self, i, disp, gi, dt, eps):
        """Active set and friction for particle i displaced ``disp`` from the step's base, with
        (frictionless) gradient gi [kg m]: returns (gi plus the friction gradient, the friction
        Hessian block [kg]).

        Releases a clearly pulling held particle, refreezes its multiplier when the driver asked for
        it (``sc.update``) or when it has none yet (held since the last freeze: it gets its first
        multiplier at its first gradient), and corrects the objective for any change of the friction
        weight (the term is linear in lam).
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
            f0, fg, fh1 = self._friction(disp, nrm, 1.0, eps)
            self.sc.f_cur[None] += (lam_new - lam_old) * f0
            gi += lam_new * fg
            fh = lam_new * fh1
        self.lam[i] = lam_new
        self.lam_end[i] = end
        return gi, fh

    @ti.func
    def project(self, i, xi, moved):
        """Trial position xi of particle i made feasible (if ``moved``): returns (the position, 1 if
        held there); records the trial's hold and normal (``accept`` takes them)."""
        hit = self.active[i]
        nrm = self.normal[i]
        if self.model.free(i) and moved:
            dist, nq = self.terrain.query(i, xi)
            if hit or dist < 0:
                xi -= dist * nq
                hit = 1
                nrm = nq
        self.trial_active[i] = hit
        self.trial_normal[i] = nrm
        return xi, hit

    @ti.func
    def frozen(self, i):
        """Whether particle i carries a frozen friction multiplier (held when it was frozen, hence
        held at every trial point of the solve too)."""
        return self.lam[i] > 0

    @ti.func
    def trial_friction(self, i, disp, eps):
        """Friction energy [kg m^2] of a ``frozen`` particle i at a trial point displaced ``disp``
        from the step's base."""
        fe, _fg, _fh = self._friction(disp, self.trial_normal[i], self.lam[i], eps)
        return fe

    @ti.func
    def accept(self, i):
        """The trial point was accepted: its holds and normals become the current ones."""
        self.active[i] = self.trial_active[i]
        self.normal[i] = self.trial_normal[i]

    @ti.func
    def filter(self, i, q):
        """q without its normal component if particle i is held (Baraff & Witkin 1998, Sec. 5.3)."""
        out = q
        if self.active[i]:
            out = q - self.normal[i].dot(q) * self.normal[i]
        return out

    @ti.func
    def bounce(self, i, vi, xi, vi_prev):
        """Velocity change [m/s] restitution asks for particle i at xi with solved velocity vi
        (``vi_prev``: its velocity at the step's start): a held particle, or one the step left inside
        the terrain's skin (``epsilon``) approaching faster than the bounce threshold.

        A held particle approached with its velocity at the start of the step (its solved normal
        velocity is about 0); below the bounce threshold it keeps what the solve gave it. A skin
        particle approaches with its solved velocity; it is held for the restitution solve, so the
        springs carry its impact to the body. (``Terrain.respond`` reflected it alone, and a stiff
        body swallowed that: the flat x1000 drop bounced at some steps and not at others.)
        Slower skin particles are left to ``respond``'s local stop: stopping them through the body
        too moved the converged tilted-plane slide 1.6 cm away from the explicit reference at
        0.1 ms (tests/test_consistency.py), where the local stop keeps it within 6.4 mm."""
        t = self.terrain
        delta = ti.Vector.zero(float, 3)
        skin = 0
        if not self.active[i] and self.model.free(i):
            dist, nq = t.query(i, xi)
            if dist < t.epsilon[None] and -nq.dot(vi) > t.bounce_threshold[None]:
                skin = 1
                self.active[i] = 1
                self.normal[i] = nq
        if self.active[i] and self.model.free(i):
            nrm = self.normal[i]
            vn = nrm.dot(vi)
            approach = nrm.dot(vi_prev)
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
