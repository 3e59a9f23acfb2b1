"""The step's scheme: backward Euler, BDF2 or SDIRK2, the same minimisation with other coefficients.

Backward Euler (BE): x_{n+1} = argmin 1/2 |x - y|_M^2 + h^2 (E + D)(x), y = x_n + h v_n + h^2 g,
v_{n+1} = (x_{n+1} - x_n) / h.

BDF2 (second order, A-stable, Gear 1971): with x^ = (4 x_n - x_{n-1}) / 3, v^ = (4 v_n - v_{n-1}) / 3
and h_e = 2 h / 3,

    x_{n+1} = argmin 1/2 |x - y|_M^2 + h_e^2 (E + D)(x),  y = x^ + h_e v^ + h_e^2 g,
    v_{n+1} = (x_{n+1} - x^) / h_e,

i.e. a backward-Euler step of length h_e from the extrapolated state (x^, v^): the driver, both
solvers, the dampers (x - x^, h_e times the velocity at the end of the step) and friction are the
same code with h_e in place of h; the solve's displacements stay from x_n (``u``), the target is
``yd`` = y - x_n and ``u_base`` = x^ - x_n (0 for backward Euler) (Hairer & Wanner, Solving ODEs
II, V.1).

BDF2 needs a smooth history. A step is taken with BDF2 only when the option asks for it and
* the previous step had the same h and ended as this one begins (no reset, no body-body contact
  response, no state set from outside: ``x_end``/``v_end`` compare exactly);
* the previous step touched nothing: no particle held or within the terrain's ``epsilon`` at its
  end, no restitution, no energy clamp (a velocity jump in the history would be extrapolated:
  after an impact v^ points away from the ground and would make a bounce of its own);
* this step touches nothing: x_n, x^ and y of every particle outside the terrain;
* the model has no grab and no body-body pairs (their step terms are written for backward Euler).
Every other step is backward Euler, so contact, friction, restitution and the clamp work exactly
as before, and the first step after any of these events starts BDF2's history again.

SDIRK2 (Alexander 1977, gamma = 1 - 1/sqrt 2: L-stable, second order, stiffly accurate), every
step, two solves (``stage`` 1 and 2, run by the driver): a backward-Euler solve of gamma h from
(x_n, v_n) to (X1, V1), then one of gamma h over the rest of the step, (1 - gamma) h, from
x^ = X1 + sqrt 2 (X1 - x_n), v^ = V1 + sqrt 2 (V1 - v_n) (the same ``u_base``/``h_eff`` path as
BDF2). A particle held on the terrain at X1 is extrapolated along the surface only, one in the
contact band but free not at all; restitution acts once, at the
step's end, from the velocity the step began with (``v_step``); the energy account is the whole
step's (``h_step``). A second stage that ends with more energy than the step began with is taken
again from (X1, V1) as backward Euler over (1 - gamma) h (``stage`` 3, counted), which keeps the
step's energy bound (docs/implicit.md, "The scheme").
"""

import taichi as ti

from ...allocation import allocate
from ...footprint import VEC, per_particle


SQRT2 = 2.0 ** 0.5
SDIRK_GAMMA = 1.0 - 1.0 / SQRT2  # Alexander's L-stable SDIRK2: both stages solve over gamma h
SDIRK_STAGE2_H = SDIRK_GAMMA / (1.0 - SDIRK_GAMMA)  # the second stage's gamma h per its time (1 - gamma) h


@ti.data_oriented
class StepScheme:
    """Each step's scheme and predictor: a part of ``ImplicitIntegrator``.

    Inputs, given at construction: the ``model`` (gravity, pinned particles), the ``terrain`` (the
    history's contact tests), the step's scalars ``sc`` (it writes ``dt_step``; it reads
    ``n_bounce`` and ``clamped`` at the step's end) and the terrain contact part (which particles
    the step left held); per step, the state, the objective's ``x_prev``/``v_prev`` (still the last
    step's start, x_{n-1} and v_{n-1}, when ``choose`` runs) and its target buffer.
    Outputs: ``u_base``, ``h_eff`` and ``bdf2_step`` (read by the objective, the driver and the
    step's end) and the target ``yd`` it writes into the objective's buffer.
    """

    BUFFERS = {
        "u_base": per_particle("x^ - x_n (0 for backward Euler) [m]", VEC),
        "x_end": per_particle("position the last step left [m]", VEC),
        "v_end": per_particle("velocity the last step left [m/s]", VEC),
        "v_step": per_particle("velocity at the start of the whole step (SDIRK2's stages) [m/s]", VEC),
    }

    def __init__(self, model, terrain, sc, contact):
        """Allocates the fields only (no write: the owner's pending SNode tree stays open); the
        option is set by ``use_bdf2``."""
        self.model = model
        self.terrain = terrain
        self.sc = sc
        self.contact = contact
        self.n = model.n_particles
        allocate(self, self.BUFFERS, self.n, 0)
        self.bdf2_on = ti.field(ti.i32, ())  # the option: 1 = BDF2 where the history allows
        self.history_ok = ti.field(ti.i32, ())  # 1: the last step left a smooth history
        self.bdf2_step = ti.field(ti.i32, ())  # 1: this step is a BDF2 step
        self.dt_last = ti.field(float, ())  # h of the last step [s]
        self.h_eff = ti.field(float, ())  # h (backward Euler) or 2 h / 3 (BDF2) of this step [s]
        self.stage = ti.field(ti.i32, ())  # SDIRK2: this solve's stage, 1, 2 or 3 (2 taken again); 0: not SDIRK2
        self.h_step = ti.field(float, ())  # SDIRK2: the energy the whole step began with [J]
        self.redo = ti.field(ti.i32, ())  # SDIRK2: 1 = the second stage gained energy; take it as BE

    def use_bdf2(self, on: bool):
        """The option ``solver.scheme``: BDF2 where the history allows (True) or backward Euler."""
        self.bdf2_on[None] = int(on)

    def reset(self):
        """No history: the next step is backward Euler."""
        self.history_ok[None] = 0

    @ti.func
    def choose(self, x: ti.template(), v: ti.template(), dt, x_prev: ti.template(), v_prev: ti.template(),
               yd: ti.template(), backward_euler_only: ti.template()):
        """Decide this step's scheme; write u_base, h_eff and the target ``yd``. Runs before
        ``x_prev``/``v_prev`` (the last step's start, x_{n-1} and v_{n-1}) are overwritten.
        ``backward_euler_only`` (a compile-time constant): the step has terms written for
        backward Euler only (body-body pairs, a grab). (Loops stay top-level for the parallel
        driver; their iterations only ever clear the flag.)"""
        m = self.model
        he = ti.cast(2.0 / 3.0, float) * dt
        g = m.gravity[None]
        stage = self.stage[None]
        self.bdf2_step[None] = self.bdf2_on[None] * self.history_ok[None] * ti.cast(self.dt_last[None] == dt, ti.i32)
        if ti.static(backward_euler_only):
            self.bdf2_step[None] = 0
        for i in range(self.n):
            if self.bdf2_step[None] and self.model.free(i):
                if any(x[i] != self.x_end[i]) or any(v[i] != self.v_end[i]):
                    self.bdf2_step[None] = 0
                if ti.static(self.terrain.has_contact):
                    ub = (x[i] - x_prev[i]) / 3.0
                    yb = ub + he * (4.0 * v[i] - v_prev[i]) / 3.0 + he * he * g
                    d0, _n0 = self.terrain.query(i, x[i])
                    d1, _n1 = self.terrain.query(i, x[i] + ub)
                    d2, _n2 = self.terrain.query(i, x[i] + yb)
                    if ti.min(d0, d1, d2) <= 0:
                        self.bdf2_step[None] = 0
        if stage > 0:
            self.bdf2_step[None] = 0
        ok = self.bdf2_step[None]
        self.h_eff[None] = he if ok else dt
        if stage == 2:
            self.h_eff[None] = SDIRK_STAGE2_H * dt
        if stage == 1:
            self.redo[None] = 0
            self.sc.g_stage[None] = 0.0
        self.sc.dt_step[None] = dt
        for i in range(self.n):
            if stage == 1:
                self.v_step[i] = v[i]
            if stage == 2 and self.model.free(i):
                self.sc.g_stage[None] += self.model.mass[i] * g.dot(x[i] - x_prev[i])
                self._stage2_base(i, x, v, dt, x_prev, v_prev, yd)
            elif ok and self.model.free(i):
                ub = (x[i] - x_prev[i]) / 3.0
                self.u_base[i] = ub
                yd[i] = ub + he * (4.0 * v[i] - v_prev[i]) / 3.0 + he * he * g
            elif self.model.free(i):
                self.u_base[i] = ti.Vector.zero(float, 3)
                yd[i] = dt * v[i] + dt * dt * g
            else:
                # pinned: moves with its own velocity over the true step; v = (u - u_base) / h_eff
                yd[i] = dt * v[i]
                self.u_base[i] = (dt - self.h_eff[None]) * v[i]

    @ti.func
    def _stage2_base(self, i, x: ti.template(), v: ti.template(), dt, x_prev: ti.template(),
                     v_prev: ti.template(), yd: ti.template()):
        """SDIRK2's second stage for particle i: a backward-Euler solve of length gamma h from
        x^ = X1 + sqrt 2 (X1 - x_n), v^ = V1 + sqrt 2 (V1 - v_n) (x, v: the first stage's X1, V1;
        x_prev, v_prev: x_n, v_n; dt: the stage's time (1 - gamma) h). A particle held on the
        terrain at X1 is extrapolated along the surface only; one within ``epsilon`` but not held
        is not extrapolated (x^ would lie inside): it starts from X1 without its inward velocity."""
        he = self.h_eff[None]
        g = self.model.gravity[None]
        ub = SQRT2 * (x[i] - x_prev[i])
        vh = v[i] + SQRT2 * (v[i] - v_prev[i])
        if ti.static(self.terrain.has_contact):
            d0, n0 = self.terrain.query(i, x[i])
            if self.contact.active[i]:
                # Held: extrapolated along the surface only (the terrain's normal impulse is no
                # force to extrapolate); friction and gravity along it act over the whole step.
                nrm = self.contact.normal[i]
                ub -= nrm.dot(ub) * nrm
                vh -= nrm.dot(vh) * nrm
            elif d0 < self.terrain.epsilon[None]:
                vh = v[i]
                vn = n0.dot(vh)
                if vn < 0:
                    vh -= vn * n0
                ub = (dt - he) * vh
        self.u_base[i] = ub
        yd[i] = ub + he * vh + he * he * g

    @ti.func
    def record(self, x: ti.template(), v: ti.template()):
        """After the step: keep its end state, and whether it leaves a smooth history."""
        self.history_ok[None] = ti.cast(self.sc.n_bounce[None] == 0 and self.sc.clamped[None] == 0, ti.i32)
        self.dt_last[None] = self.sc.dt_step[None]
        for i in range(self.n):
            self.x_end[i] = x[i]
            self.v_end[i] = v[i]
            if ti.static(self.terrain.has_contact):
                if self.model.free(i):
                    d, _n = self.terrain.query(i, x[i])
                    if self.contact.active[i] or d < self.terrain.epsilon[None]:
                        self.history_ok[None] = 0
