"""Explicit integrators on the full state y = (x, v), y' = (v, a(x, v)).

``SemiImplicitEuler`` (symplectic Euler) is its own class; explicit Euler, midpoint and RK4 are
one generic explicit Runge-Kutta method driven by their Butcher tableaus, so each is exactly the
textbook method (RK4: y_{n+1} = y_n + dt/6 (k1 + 2 k2 + 2 k3 + k4)).
"""

import taichi as ti

from .base import Integrator, register


@ti.data_oriented
class ExplicitRungeKutta(Integrator):
    """Generic explicit Runge-Kutta method on (x, v) given a Butcher tableau (A, b).

    Stage s evaluates k_s = f(y_n + dt sum_j A[s][j] k_j), k = (velocity, acceleration);
    y_{n+1} = y_n + dt sum_s b[s] k_s. Zero coefficients are skipped at compile time.
    """

    A: list = []
    b: list = []

    def __init__(self, model, terrain, options=None):
        super().__init__(model, terrain, options)
        stages = len(self.b)
        # Stage derivatives k_s = (velocity [m/s], acceleration [m/s^2]); stage 0's velocity is v.
        self.kx = [None] + [ti.Vector.field(3, float, self.n) for _ in range(stages - 1)]
        self.kv = [ti.Vector.field(3, float, self.n) for _ in range(stages)]
        self.xs = ti.Vector.field(3, float, self.n)  # stage state
        self.vs = ti.Vector.field(3, float, self.n)

    @ti.func
    def _step_body(self, x: ti.template(), v: ti.template(), dt, step):
        A, b = ti.static(self.A, self.b)
        for s in ti.static(range(len(b))):
            if ti.static(s == 0):
                self.forces.compute(x, v, dt, self.kv[0])
            else:
                for i in range(self.n):
                    xi, vi = x[i], v[i]
                    for j in ti.static(range(s)):
                        if ti.static(A[s][j] != 0):
                            xi += (dt * A[s][j]) * self._kx(j, v, i)
                            vi += (dt * A[s][j]) * self.kv[j][i]
                    self.xs[i] = xi
                    self.vs[i] = vi
                    self.kx[s][i] = vi
                self.forces.compute(self.xs, self.vs, dt, self.kv[s])
        for i in range(self.n):
            xn, vn = x[i], v[i]
            for s in ti.static(range(len(b))):
                if ti.static(b[s] != 0):
                    xn += (dt * b[s]) * self._kx(s, v, i)
                    vn += (dt * b[s]) * self.kv[s][i]
            self._finish(i, x, v, xn, vn, step)

    @ti.func
    def _kx(self, s: ti.template(), v: ti.template(), i):
        """Stage s's velocity for particle i (stage 0's is the start-of-step velocity)."""
        r = v[i]
        if ti.static(s > 0):
            r = self.kx[s][i]
        return r


@register
@ti.data_oriented
class ExplicitEuler(ExplicitRungeKutta):
    """x_{n+1} = x_n + dt v_n;  v_{n+1} = v_n + dt a(x_n, v_n). First order."""

    name = "explicit_euler"
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
    order = 1
    force_evals = 1
    description = "symplectic Euler: velocity first, then position with the new velocity (1 force eval)"

    def __init__(self, model, terrain, options=None):
        super().__init__(model, terrain, options)
        self.a = ti.Vector.field(3, float, self.n)

    @ti.func
    def _step_body(self, x: ti.template(), v: ti.template(), dt, step):
        self.forces.compute(x, v, dt, self.a)
        for i in range(self.n):
            vn = v[i] + dt * self.a[i]
            self._finish(i, x, v, x[i] + dt * vn, vn, step)


@register
@ti.data_oriented
class Midpoint(ExplicitRungeKutta):
    """Explicit midpoint: slope evaluated at y_n + dt/2 f(y_n). Second order."""

    name = "midpoint"
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
    order = 4
    force_evals = 4
    description = "classic Runge-Kutta, fourth order (4 force evals)"
    A = [[], [0.5], [0.0, 0.5], [0.0, 0.0, 1.0]]
    b = [1 / 6, 1 / 3, 1 / 3, 1 / 6]
