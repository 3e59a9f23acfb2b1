"""Phase 4 of the implicit step, its end: velocities from the solve, restitution as a velocity
step through the body (restitution.py) and the body-body responses, scaled to the energy the step
lost, the solver's ``finish`` (``Integrator._finish``: ``Terrain.respond``, the divergence check),
and, as a counted last resort, the energy clamp. Its phases are walked by both drivers (walk.py).
"""

import taichi as ti

from ...allocation import allocate
from ...footprint import VEC, per_particle


@ti.data_oriented
class StepEnd:
    """The end of a step (phase 4): a part of ``ImplicitIntegrator``.

    Given at construction: the ``model``, the ``terrain``, the step's scalars ``sc`` (it reads the
    energies the objective and the start left there: h_start, h_scale, e_cur; it writes k_solve,
    g_end, n_bounce, bounce_a, bounce_b, k_end, bounce_limited, clamped), the ``objective`` (u, v_n,
    the residual), the terrain ``contact`` and its restitution ``spread``, the ``scheme`` (u_base,
    and it records the step's end), the ``accounts`` (it records the step), ``finish``, the
    solver's ti.func ``finish(i, x, v, x_i, v_i, step)`` that stores particle i's end of step
    (``Integrator._finish``: the terrain's response, the divergence check), and ``tol2``, the
    solver's field of the tolerance on ``sc.res2`` the accounts judge the step's residual by. Nothing
    else of the solver. ``pairs`` (pairs.PairContacts) is given by the solver with its body-body
    pairs; None: no pair code.
    """

    BUFFERS = {
        "v_new": per_particle("velocity from the solve [m/s]", VEC),
        "dv": per_particle("restitution's velocity change [m/s]", VEC),
    }

    def __init__(self, model, terrain, sc, objective, contact, spread, scheme, accounts, finish, tol2):
        """Allocates the fields only (no write: the owner's pending SNode tree stays open)."""
        self.model, self.terrain, self.sc, self.objective = model, terrain, sc, objective
        self.contact, self.spread, self.scheme, self.accounts = contact, spread, scheme, accounts
        self.finish_particle, self.tol2 = finish, tol2
        self.pairs = None
        self.n = model.n_particles
        allocate(self, self.BUFFERS, self.n, 0)
        self.clamp_on = ti.field(ti.i32, ())  # 1: the last-resort clamp is on (the solver's option)
        self.energy_tol = ti.field(float, ())  # relative energy growth counted as round-off

    def _has_pairs(self) -> bool:
        return self.pairs is not None

    @ti.func
    def velocities(self, x: ti.template(), dt):
        """Solved velocities v = (u - u_base)/h_e ((x - x_n)/h for backward Euler; dt: this step's
        h_eff), and the restitution each held particle asks for (its normal part prescribed for the
        spread, restitution.py; the tangential friction loss kept local) and the body-body responses."""
        m = self.model
        self.sc.k_solve[None] = 0.0
        self.sc.g_end[None] = 0.0
        self.sc.n_bounce[None] = 0.0
        if ti.static(not self.terrain.has_contact):
            self._translate(x)
        if ti.static(self._has_pairs()):
            self.pairs.end(x, dt)
        for i in range(self.n):
            vi = (self.objective.u[i] - self.scheme.u_base[i]) / dt
            delta = ti.Vector.zero(float, 3)
            if ti.static(self.terrain.has_contact):
                # SDIRK2 bounces once, at the step's end, from the whole step's approach: a bounce
                # at the first stage would be extrapolated into the second.
                stage = self.scheme.stage[None]
                ask = ti.Vector.zero(float, 3)
                if stage != 1:
                    approach = self.objective.v_prev[i]
                    if stage >= 2:
                        approach = self.scheme.v_step[i]
                    ask = self.contact.bounce(i, vi, x[i], approach)
                delta = self.spread.split(i, ask)
            if ti.static(self._has_pairs()):
                delta += self.pairs.dv[i]
            self.v_new[i] = vi
            self.dv[i] = delta
            if self.model.free(i):
                self.sc.k_solve[None] += 0.5 * m.mass[i] * vi.dot(vi)
                self.sc.g_end[None] -= m.mass[i] * m.gravity[None].dot(self.objective.u[i])

    @ti.func
    def _translate(self, x: ti.template()):
        """The objective's exact minimum over rigid translations (free space only), the residual it
        leaves recorded as the last gradient's (so the reported residual is the returned state's)."""
        if self.objective.translation_minimum(x):
            res = self.objective.residual()
            self.accounts.residual_at(self.sc.evals[None] - 1, res)
            self.sc.res_prev[None] = res

    @ti.func
    def finish(self, x: ti.template(), v: ti.template(), step):
        """After the restitution spread: every restitution and body-body response scaled to the energy
        the step lost; the solver's ``finish`` per particle; then, if the step still ends with more
        energy than it began with (beyond round-off), the counted clamp."""
        m = self.model
        scale = ti.cast(1.0, float)
        if ti.static(self.terrain.has_contact or self._has_pairs()):
            self.sc.bounce_a[None] = 0.0
            self.sc.bounce_b[None] = 0.0
            for i in range(self.n):
                delta = self.spread.total(i, self.dv[i])
                self.dv[i] = delta
                if self.model.free(i):
                    self.sc.bounce_a[None] += 0.5 * m.mass[i] * delta.dot(delta)
                    self.sc.bounce_b[None] += m.mass[i] * self.v_new[i].dot(delta)
            lost = self.sc.h_start[None] - (self.sc.k_solve[None] + self.sc.g_end[None] + self.sc.e_cur[None])
            scale = self._bounce_scale(lost)
        self.sc.k_end[None] = 0.0
        for i in range(self.n):
            self.finish_particle(i, x, v, x[i], self.v_new[i] + scale * self.dv[i], step)
            if self.model.free(i):
                self.sc.k_end[None] += 0.5 * m.mass[i] * v[i].dot(v[i])
        # Last resort, counted in stats(): take the excess out of the kinetic energy.
        excess = self.sc.k_end[None] + self.sc.g_end[None] + self.sc.e_cur[None] - self.sc.h_start[None]
        f = ti.cast(1.0, float)
        noise = self.sc.h_scale[None] + self.sc.k_end[None] + ti.abs(self.sc.g_end[None])  # scale of its round-off
        if self.scheme.stage[None] == 2 and excess > self.energy_tol[None] * noise:
            self.scheme.redo[None] = 1  # SDIRK2: this stage is taken again as backward Euler
        elif self.clamp_on[None] and excess > self.energy_tol[None] * noise:
            self.sc.clamped[None] = 1
            k_end = self.sc.k_end[None]
            if k_end > 0:
                f = ti.sqrt(ti.max(k_end - excess, 0.0) / k_end)
        for i in range(self.n):
            if f < 1.0 and self.model.free(i):
                v[i] *= f
        self.scheme.record(x, v)
        self.accounts.record(self.objective.residual(), self.tol2[None])

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
