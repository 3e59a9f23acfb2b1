"""Explicit integrators on the full state y = (x, v), y' = (v, a(x, v)).

``SemiImplicitEuler`` (symplectic Euler) is its own class; explicit Euler, midpoint and RK4 are
one generic explicit Runge-Kutta method driven by their Butcher tableaus, so each is exactly the
textbook method (RK4: y_{n+1} = y_n + dt/6 (k1 + 2 k2 + 2 k3 + k4)).

Every step is made of fused passes: one loop per force evaluation that computes each
particle's acceleration and at once what the method does with it (the next stage state, the
running sum of the final combination, or the new state), with no acceleration buffer.
With gathered forces a pass reads its neighbours' state, so it must not overwrite the state it
reads: RK stages alternate between two stage buffers and the last stage writes the step's
result in place (it reads neighbours only from a stage buffer); one-stage methods ping-pong the
state itself (``Integrator.ping_pong``).
"""

from dataclasses import dataclass
from typing import ClassVar

import taichi as ti

from ..allocation import page_aligned_vectors
from ..footprint import VEC, Buffers, FieldCounts, per_particle
from ...errors import UserError
from ..stencil import GATHERING, NAME as STENCIL
from .base import MB, ExplicitConfig, Integrator, register
from . import linear_stability


@ti.data_oriented
class ExplicitRungeKutta(Integrator):
    """Generic explicit Runge-Kutta method on (x, v) given a Butcher tableau (A, b).

    Stage s evaluates k_s = f(y_n + dt sum_j A[s][j] k_j), k = (velocity, acceleration);
    y_{n+1} = y_n + dt sum_s b[s] k_s. Zero coefficients are skipped at compile time.
    """

    A: list = []
    b: list = []

    def __init__(self, model, terrain, options=None, contacts=None):
        super().__init__(model, terrain, options, contacts)
        stages = len(self.b)
        if self.uses_ping_pong(self.options):
            self._use_ping_pong()
        self._kept = self._kept_stages()
        self.kx = [ti.Vector.field(3, float, self.n) if self._kept[j] else None for j in range(stages)]
        self.kv = [ti.Vector.field(3, float, self.n) if self._kept[j] else None for j in range(stages)]
        # Two stage-state buffers (stage s reads buffer s % 2 ... written by stage s - 1) and
        # the running sums x_n + dt sum b_j kx_j, v_n + dt sum b_j kv_j of the stages so far.
        self.xs, self.vs, self.x_acc, self.v_acc = [], [], None, None
        if stages > 1:
            xs0, xs1, vs0, vs1, self.x_acc, self.v_acc = page_aligned_vectors(self.n, 6)
            self.xs, self.vs = [xs0, xs1], [vs0, vs1]

    @classmethod
    def _a(cls, s, j):
        return cls.A[s][j] if j < len(cls.A[s]) else 0.0

    @classmethod
    def _kept_stages(cls) -> list[bool]:
        """Stage derivatives k_j kept only where a stage after the next one still needs them
        (none of the tableaus here: each stage uses only the one before it)."""
        stages = len(cls.b)
        return [any(cls._a(t, j) != 0 for t in range(j + 2, stages)) for j in range(stages)]

    @classmethod
    def uses_ping_pong(cls, options) -> bool:
        """One stage with gathered forces reads the old state while writing the new: ping-pong."""
        return len(cls.b) == 1 and options.forces in GATHERING

    @classmethod
    def buffers(cls, options, arch, counts, real_bytes) -> Buffers:
        """The force pass's and ping-pong buffers (``Integrator.buffers``), the kept stage derivatives
        kx, kv, and with two stages or more the two stage states and the running sums."""
        stages = 6 * sum(cls._kept_stages()) + (18 if len(cls.b) > 1 else 0)
        return super().buffers(options, arch, counts, real_bytes) + Buffers(FieldCounts(stages))

    @ti.func
    def _step_body(self, x: ti.template(), v: ti.template(), dt, step):
        """In place: stage passes through the stage buffers, the last one writes (x, v)."""
        for s in ti.static(range(len(self.b))):
            xr, vr, xw, vw = ti.static(*self._stage_buffers(s, x, v))
            self._stage(x, v, xr, vr, xw, vw, dt, step, s)

    def _stage_buffers(self, s, x, v):
        """(read x, read v, write x, write v) of stage s: stage s reads buffer s % 2 (stage 0 the
        state), writes buffer (s + 1) % 2 (the last stage the state)."""
        xr, vr = (x, v) if s == 0 else (self.xs[s % 2], self.vs[s % 2])
        xw, vw = (x, v) if s == len(self.b) - 1 else (self.xs[(s + 1) % 2], self.vs[(s + 1) % 2])
        return xr, vr, xw, vw

    @ti.func
    def _step_into(self, x: ti.template(), v: ti.template(), xo: ti.template(), vo: ti.template(), dt, step):
        """One-stage methods with gathered forces: read (x, v), write the new state to (xo, vo)."""
        self._stage(x, v, x, v, xo, vo, dt, step, 0)

    @ti.func
    def _stage(self, x: ti.template(), v: ti.template(), xr: ti.template(), vr: ti.template(), xw: ti.template(),
               vw: ti.template(), dt, step, s: ti.template()):
        """Stage s: k_s at stage state (xr, vr); write stage s + 1's state, or the new state, to (xw, vw).

        (x, v) is the start-of-step state, read at particle i only.
        """
        A, b = ti.static(self.A, self.b)
        last = ti.static(s == len(b) - 1)
        self.forces.spring_pass(xr, vr)
        for i in range(self.n):
            kx = vr[i]
            kv = self.forces.accel(xr, vr, i, dt)
            if ti.static(self._kept[s]):
                self.kx[s][i] = kx
                self.kv[s][i] = kv
            # running sum of the final combination, in the order of the textbook sum
            xn, vn = x[i], v[i]
            if ti.static(s > 0):
                xn, vn = self.x_acc[i], self.v_acc[i]
            if ti.static(b[s] != 0):
                xn += (dt * b[s]) * kx
                vn += (dt * b[s]) * kv
            if ti.static(last):
                self._finish(i, xw, vw, xn, vn, step)
            else:
                self.x_acc[i] = xn
                self.v_acc[i] = vn
                # stage s + 1's state: y_n + dt sum_j A[s+1][j] k_j
                t = ti.static(s + 1)
                xi, vi = x[i], v[i]
                for j in ti.static(range(t)):
                    if ti.static(self._a(t, j) != 0):
                        if ti.static(j == s):
                            xi += (dt * A[t][j]) * kx
                            vi += (dt * A[t][j]) * kv
                        else:
                            xi += (dt * A[t][j]) * self.kx[j][i]
                            vi += (dt * A[t][j]) * self.kv[j][i]
                xw[i] = xi
                vw[i] = vi


@register
@ti.data_oriented
class ExplicitEuler(ExplicitRungeKutta):
    """x_{n+1} = x_n + dt v_n;  v_{n+1} = v_n + dt a(x_n, v_n). First order."""

    name = "explicit_euler"
    amplification = staticmethod(linear_stability.taylor(1))
    sweep_dt_cap = 2e-3
    BASE_BYTES = 138 * MB  # measured (memory.py): process, runtime, compiled kernels
    order = 1
    force_evals = 1
    description = "forward Euler: both updates from the start-of-step state (1 force eval)"
    A = [[]]
    b = [1.0]


@register
@ti.data_oriented
class SemiImplicitEuler(Integrator):
    """v_{n+1} = v_n + dt a(x_n, v_n);  x_{n+1} = x_n + dt v_{n+1}. First order, symplectic."""

    name = "semi_implicit_euler"
    answers_at_crossing = True
    amplification = staticmethod(linear_stability.symplectic_euler)
    sweep_dt_cap = 2e-3
    BASE_BYTES = 138 * MB  # measured (memory.py): process, runtime, compiled kernels
    order = 1
    force_evals = 1
    description = "symplectic Euler: velocity first, then position with the new velocity (1 force eval)"

    def __init__(self, model, terrain, options=None, contacts=None):
        super().__init__(model, terrain, options, contacts)
        if self.uses_ping_pong(self.options):
            self._use_ping_pong()

    @classmethod
    def uses_ping_pong(cls, options) -> bool:
        """Gathered forces read the old state while the step writes the new: ping-pong."""
        return options.forces in GATHERING

    @ti.func
    def _step_body(self, x: ti.template(), v: ti.template(), dt, step):
        """In place (per_spring forces: the particle loop reads only stored spring forces)."""
        self._step_into(x, v, x, v, dt, step)

    @ti.func
    def _step_into(self, x: ti.template(), v: ti.template(), xo: ti.template(), vo: ti.template(), dt, step):
        self.forces.spring_pass(x, v)
        for i in range(self.n):
            vn = v[i] + dt * self.forces.accel(x, v, i, dt)
            xn, vn = self._drift(i, x[i], vn, ti.Vector.zero(float, 3), dt)
            xo[i] = xn
            vo[i] = vn
            self._check_divergence(vn, step)


@register
@ti.data_oriented
class VelocityVerlet(Integrator):
    """Kick-drift-kick velocity Verlet with the force carried between steps. Second order.

    v_{n+1/2} = v_n + dt/2 a_n;  x_{n+1} = x_n + dt v_{n+1/2};
    a_{n+1} = a(x_{n+1}, v_{n+1/2} + dt/2 a_n);  v_{n+1} = v_{n+1/2} + dt/2 a_{n+1}.

    a_{n+1} is kept (``accel``) for the next step's first kick, and the first step of a run (or
    after ``reset`` or a model change) evaluates a_0 once. The damper needs v_{n+1}, which depends
    on a_{n+1}: the force pass takes it at the linear prediction v_n + dt a_n, then a damper-only
    corrector re-predicts v_{n+1} = v_{n+1/2} + dt/2 a_{n+1} from that force and evaluates the
    dampers again there (their direction at x_{n+1}; linear in the velocity, so only the change of
    the prediction is summed), and contact at that velocity. With the prediction alone the damper's
    extrapolation halves the stability limit where dampers dominate (g dt < 1 against symplectic
    Euler's 2); with the corrector it is symplectic Euler's or above (docs/benchmarks/VERLET.md).
    Both keep the method second order. The corrector is a second pass over the springs: about
    twice semi-implicit Euler's cost per step. Without dampers it is leapfrog: symplectic,
    time-reversible. The terrain answers the drift (``_drift``); no pass writes what a neighbour
    reads in the same loop, so every force strategy steps in place.
    """

    @dataclass(frozen=True)
    class Config(ExplicitConfig):
        """The explicit options; the damper-only corrector reads the stored springs, so not the stencil."""

        auto_stencil: ClassVar[bool] = False

        def resolve(self, arch: str, fast_math: bool, counts) -> "ExplicitConfig":
            out = super().resolve(arch, fast_math, counts)
            if out.forces == STENCIL:
                raise UserError("velocity_verlet: solver.forces = stencil is not supported (its damper "
                                "corrector reads the stored springs); use gather or scatter")
            return out

    name = "velocity_verlet"
    answers_at_crossing = True
    amplification = staticmethod(linear_stability.velocity_verlet)
    sweep_dt_cap = 2e-3  # with the damper corrector its linear limit is semi-implicit Euler's (1.9 ms on the default cube)
    # measured (memory.py), peak RSS cold / warm cache: 147 / 127 MB, beside semi-implicit Euler's 150 / 129
    BASE_BYTES = 138 * MB
    order = 2
    force_evals = 1
    description = "kick-drift-kick velocity Verlet, dampers at the re-predicted velocity (1 force eval + a damper pass)"
    BUFFERS = {"accel": per_particle("the last step's end acceleration a_n [m/s^2]", VEC),
               "v_pred": per_particle("the predicted end-of-step velocity the damper reads [m/s]", VEC),
               "dv": per_particle("the corrector's change of the predicted velocity [m/s]", VEC),
               "f_first": per_particle("the first force pass's spring and damper sum [N]", VEC)}

    @classmethod
    def spring_passes_per_step(cls, stats: dict) -> float:
        """The force pass and the dampers' corrector pass, both over all springs."""
        return 2.0

    def __init__(self, model, terrain, options=None, contacts=None):
        super().__init__(model, terrain, options, contacts)
        self._primed = False  # whether ``accel`` holds a_n of the state to step

    def advance(self, state, dt: float, n_steps: int) -> int:
        if n_steps > 0 and not self.diverged and not self._primed:
            self._prime(state.x, state.v, dt)
            self._primed = True
        return super().advance(state, dt, n_steps)

    def reset(self):
        super().reset()
        self._primed = False

    def notify_model_changed(self, flags: int):
        super().notify_model_changed(flags)
        self._primed = False  # the carried force was the old model's

    @ti.kernel
    def _prime(self, x: ti.template(), v: ti.template(), dt: float):
        """accel = a(x, v): the start of the first step."""
        self._refresh()
        if ti.static(self._serial()):
            ti.loop_config(serialize=True)  # the serial force pass (plain scatter adds) on one thread
            for _ in range(1):
                self._evaluate(x, v, dt)
        else:
            self._evaluate(x, v, dt)

    @ti.func
    def _evaluate(self, x: ti.template(), v: ti.template(), dt):
        self.forces.spring_pass(x, v)
        for i in range(self.n):
            self.accel[i] = self.forces.accel(x, v, i, dt)

    @ti.func
    def _step_body(self, x: ti.template(), v: ti.template(), dt, step):
        """In place: kick and drift (each particle reads only itself), then the force pass at the
        new positions and predicted velocities (v_pred, not written in that loop) and the kick."""
        half = 0.5 * dt
        for i in range(self.n):
            a = self.accel[i]
            xn, vh = self._drift(i, x[i], v[i] + half * a, a, dt)
            x[i] = xn
            v[i] = vh
            self.v_pred[i] = vh + half * a
        self.forces.spring_pass(x, self.v_pred)
        for i in range(self.n):
            f = self.forces.spring_sum(x, self.v_pred, i)
            a = self.forces.particle_accel(x, self.v_pred, i, f, dt)
            self.f_first[i] = f
            self.dv[i] = half * (a - self.accel[i])  # the re-predicted velocity vh + dt/2 a, less v_pred
        self.forces.damper_pass(x, self.dv)
        for i in range(self.n):
            f = self.f_first[i] + self.forces.damper_sum(x, self.dv, i)
            self.v_pred[i] = self.v_pred[i] + self.dv[i]  # read at i only in this loop
            a = self.forces.particle_accel(x, self.v_pred, i, f, dt)
            self.accel[i] = a
            vn = v[i] + half * a
            v[i] = vn
            self._check_divergence(vn, step)


@register
@ti.data_oriented
class Midpoint(ExplicitRungeKutta):
    """Explicit midpoint: slope evaluated at y_n + dt/2 f(y_n). Second order."""

    name = "midpoint"
    amplification = staticmethod(linear_stability.taylor(2))
    sweep_dt_cap = 4e-3
    BASE_BYTES = 142 * MB  # measured (memory.py): process, runtime, compiled kernels
    order = 2
    force_evals = 2
    description = "explicit midpoint (RK2): slope at the half-step state (2 force evals)"
    A = [[], [0.5]]
    b = [0.0, 1.0]


@register
@ti.data_oriented
class RK4(ExplicitRungeKutta):
    """Classic fourth-order Runge-Kutta."""

    name = "rk4"
    amplification = staticmethod(linear_stability.taylor(4))
    sweep_dt_cap = 6e-3
    BASE_BYTES = 147 * MB  # measured (memory.py): process, runtime, compiled kernels
    order = 4
    force_evals = 4
    description = "classic Runge-Kutta, fourth order (4 force evals)"
    A = [[], [0.5], [0.0, 0.5], [0.0, 0.0, 1.0]]
    b = [1 / 6, 1 / 3, 1 / 3, 1 / 6]
