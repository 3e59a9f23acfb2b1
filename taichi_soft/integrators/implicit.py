"""Implicit integrators: backward Euler by Newton + PCG, and fast mass-spring (local/global).

Both take the backward-Euler step as an energy minimisation (see docs/implicit.md):

    x_{n+1} = argmin_x g(x),  g(x) = 1/2 (x - y)^T M (x - y) + h^2 E(x) + h^2 D(x)
    y = x_n + h v_n + h^2 g_grav,   v_{n+1} = (x_{n+1} - x_n) / h

E is the spring energy sum_s k_s/2 (|x_a - x_b| - r_s)^2. Dampers are implicit too, through the
Rayleigh dissipation function of each damper with its direction l_s frozen at the start of the
step: h^2 D(x) = sum_s h kd_s / 2 (l_s . (u_a - u_b))^2, u = x - x_n. Its gradient divided by h^2
is exactly the seed's damper force -kd ((v_a - v_b) . l) l at v = u / h, so g is the same
objective for both solvers, convex in the damper part, and its minimiser is a backward-Euler
step of springs and dampers (with the damper direction lagged by one step).

* ``implicit_euler``: Newton's method on g with a PSD-projected Hessian applied matrix-free
  (Baraff & Witkin 1998 for the implicit mass-spring step, Choi & Ko 2002 for the clamp), PCG
  with a 3x3 block-Jacobi preconditioner, a backtracking (Armijo) line search on g.
* ``fast_mass_spring``: the local/global solver of Liu et al. 2013: the local step projects each
  spring onto its rest length, d_s = r_s (x_a - x_b)/|x_a - x_b| (and each damper onto the plane
  normal to l_s); the global step solves the constant system (M + L) dx = -grad g, L the graph
  Laplacian with weights h^2 k_s + h kd_s, prefactorised (skyline Cholesky) and refactorised only
  when dt, a stiffness or a damper coefficient changes. PCG on the same matrix is the fallback.

Contact (the same for both, inside the iteration, see docs/implicit.md): the terrain is an
inequality constraint d(x_i) >= 0. Iterates are projected onto the terrain surface; a projected
particle is held on the surface (Newton filters its normal direction out of the linear system,
Baraff & Witkin 1998 Sec. 5.3) until the gradient pulls it off (negative multiplier). Coulomb
friction is a term of the objective too: a smoothed |tangential displacement| weighted by mu times
the lagged multiplier (the lagged dissipative potential of Li et al. 2020, IPC), so it is part of
the same minimisation and cannot add energy. After the solve, restitution on the pre-impact
normal velocity is applied, and ``Integrator._finish`` runs ``Terrain.respond`` and the
divergence check as for every method.
"""

import numpy as np
import taichi as ti

from ..forces import spring_energy, spring_energy_derivatives
from ..linalg import PCG, SkylineCholesky
from .base import Integrator, register

# Slots of the per-step scalar field ``sc``.
_RES2 = 0  # squared residual norm sum_i |r_i|^2 / m_i [kg m^2]
_F_CUR = 1  # objective at the current iterate [kg m^2]
_F_TRIAL = 2  # objective at the line-search trial point
_DEC = 3  # grad . (x_trial - x), the first-order decrease predicted for the trial [kg m^2]
_N_ACTIVE = 4  # particles held on the terrain after the last gradient evaluation
_N_SC = 5

# Slots of the stats accumulator ``acc`` (sums over steps since the last stats() call).
_A_STEPS, _A_OUTER, _A_CG, _A_LS, _A_RES = range(5)
_N_ACC = 5
CHOLESKY_AUTO_MAX = 10_000_000  # largest factor envelope [values] global_solver = "auto" factorises
RES_HISTORY = 64  # residuals of the last step's iterations kept for inspection and tests


def _int_at_least(lo):
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= lo


def _number_in(lo, hi, lo_open=False):
    def check(v):
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v):
            return False
        return (v > lo if lo_open else v >= lo) and v <= hi
    return check


# Options both implicit integrators take (contact handling inside the solve).
_CONTACT_OPTIONS = {
    "friction_velocity": (1e-3, _number_in(0.0, 1.0, lo_open=True),
                          "a number in (0, 1] (sliding speed in m/s below which friction is smoothed)"),
}


@ti.data_oriented
class ImplicitIntegrator(Integrator):
    """Shared machinery: predictor, objective, gradient, contact constraints and step end.

    Subclasses implement ``_solve_step(x, dt)`` (serial ti.func: iterate from the predictor to
    x_{n+1}) and ``_solve_step_python(state, dt)`` (the same from Python, one launch per phase).
    """

    implicit = True
    order = 1
    force_evals = 0

    def __init__(self, model, terrain, options=None):
        super().__init__(model, terrain, options)
        n, m = self.n, max(model.n_springs, 1)
        vec = lambda size: ti.Vector.field(3, float, size)  # noqa: E731
        self.x_prev = vec(n)  # x_n [m]
        self.v_prev = vec(n)  # v_n [m/s]
        self.y = vec(n)  # inertial target x_n + h v_n + h^2 g [m]
        self.grad = vec(n)  # gradient of the objective [kg m]
        self.rhs = vec(n)  # -grad with constrained normal components removed [kg m]
        self.dx = vec(n)  # step of the current iteration [m]
        self.x_trial = vec(n)
        self.normal = vec(n)  # terrain normal of a constrained particle
        self.trial_normal = vec(n)
        self.active = ti.field(ti.i32, n)  # 1 = held on the terrain surface in this step
        self.lam = ti.field(float, n)  # lagged contact multiplier h^2 |F_n| of a held particle [kg m]
        self.fric_hess = ti.Matrix.field(3, 3, float, n)  # Hessian block of its friction term [kg]
        self.fric_eps = ti.field(float, ())  # friction smoothing length friction_velocity * h [m]
        self.trial_active = ti.field(ti.i32, n)
        self.spring_dir = vec(m)  # damper direction l_s at x_n (frozen over the step)
        self.spring_grad = vec(m)  # d(h^2 (E + D))/dx_a per spring [kg m]
        self.sc = ti.field(float, _N_SC)
        self.acc = ti.field(ti.f64, _N_ACC)
        self.res_history = ti.field(float, RES_HISTORY)  # residual [m/s^2] after each iteration of the last step
        self.n_history = ti.field(ti.i32, ())
        self.total_mass = float(np.sum(model.mass_np[model.mass_np > 0])) or 1.0
        # Tolerance on the squared residual sum, from the option in m/s^2 (see _residual()).
        self.tol2 = ti.field(float, ())
        self.h2 = ti.field(float, ())  # h^2 of the current step [s^2]
        eps = np.finfo(model.real).eps
        self.roundoff = ti.field(float, ())  # relative objective noise the line search ignores
        self.roundoff[None] = 16 * eps
        self.friction_velocity = float(self.options["friction_velocity"])

    # -- per-step phases (ti.func made of top-level loops) -------------------------------------
    @ti.func
    def _free(self, i):
        """Pinned particles (inverse mass 0) follow their own velocity and are not solved for."""
        return self.model.inv_mass[i] > 0

    @ti.func
    def _begin_step(self, x: ti.template(), v: ti.template(), dt):
        """Save (x_n, v_n), freeze damper directions, predict y and start from it, projected."""
        m = self.model
        self.h2[None] = dt * dt
        self.fric_eps[None] = self.friction_velocity * dt
        for s in range(m.n_springs):
            d = x[m.spring_ends[s][0]] - x[m.spring_ends[s][1]]
            length = d.norm()
            self.spring_dir[s] = d / length if length > 0 else ti.Vector.zero(float, 3)
        for i in range(self.n):
            self.x_prev[i] = x[i]
            self.v_prev[i] = v[i]
            yi = x[i] + dt * v[i]
            if self._free(i):
                yi += dt * dt * m.gravity[None]
            self.y[i] = yi
            self.active[i] = 0
            self.lam[i] = 0.0
            self.normal[i] = ti.Vector([0.0, 1.0, 0.0], dt=float)
            if ti.static(self.terrain.has_contact):
                if self._free(i):
                    dist, nrm = self.terrain.query(i, yi)
                    if dist < 0:
                        yi -= dist * nrm
                        self.active[i] = 1
                        self.normal[i] = nrm
            x[i] = yi

    @ti.func
    def _friction(self, i, xi, nrm, lam):
        """Friction term of a held particle at xi: (energy [kg m^2], gradient [kg m], Hessian [kg]).

        mu lam f0(|u_t|), u_t = (I - N N^T)(xi - x_n) the tangential displacement over the step and
        f0 the Huber function (|u_t| beyond eps = friction_velocity * h, quadratic below), so the
        gradient is mu lam u_t/|u_t|: Coulomb's bound mu |F_n| times h^2 (lam = h^2 |F_n|, lagged).
        Below eps the friction is a stiff tangential spring (a particle may creep at most at about
        friction_velocity); beyond it the Hessian returned is that of a quadratic majorant.
        """
        tp = ti.Matrix.identity(float, 3) - nrm.outer_product(nrm)
        u = tp @ (xi - self.x_prev[i])
        sl = u.norm()
        eps = self.fric_eps[None]
        c = self.terrain.friction[None] * lam
        energy = ti.cast(0.0, float)
        grad = ti.Vector.zero(float, 3)
        hess = ti.Matrix.zero(float, 3, 3)
        if sl < eps:
            energy = 0.5 * c * sl * sl / eps
            grad = (c / eps) * u
            hess = (c / eps) * tp
        else:
            t = u / sl
            energy = c * (sl - 0.5 * eps)
            grad = c * t
            # The Hessian of the quadratic majorant c |u|^2 / (2 |u_t|) + c |u_t| / 2 rather than
            # the exact c / |u_t| (T - t t^T): a Newton step then never carries the particle past
            # the point where friction stops it (iteratively reweighted least squares), which
            # the exact, zero curvature along t would; it stays PSD and continuous at eps.
            hess = (c / sl) * tp
        return energy, grad, hess

    @ti.func
    def _gradient(self, x: ti.template(), dt, with_hessian: ti.template()):
        """grad g(x), the filtered residual ``rhs`` and its norm; releases pulling contacts.

        With ``with_hessian`` also stores each spring's 3x3 Hessian block (``spring_hess``) and
        each particle's inverse diagonal block (``precond``) for the Newton solve.

        Friction: each held particle's multiplier lam = grad . N (h^2 times the normal force) is
        updated here from the current iterate and used until the next gradient (lagged by one
        iteration, as in IPC); the objective at x (``_F_CUR``) is corrected for the change, so the
        line search compares like with like. A released particle loses its friction term.
        """
        m = self.model
        h = dt
        for s in range(m.n_springs):
            a, b = m.spring_ends[s][0], m.spring_ends[s][1]
            grp = m.spring_group[s]
            ge, he = spring_energy_derivatives(m, x, a, b, m.spring_rest[s], grp)
            l = self.spring_dir[s]
            u = (x[a] - self.x_prev[a]) - (x[b] - self.x_prev[b])
            kd = m.group_kd[grp]
            self.spring_grad[s] = h * h * ge + (h * kd * l.dot(u)) * l
            if ti.static(with_hessian):
                self.spring_hess[s] = h * h * he + (h * kd) * l.outer_product(l)
        self.sc[_RES2] = 0.0
        self.sc[_N_ACTIVE] = 0.0
        for i in range(self.n):
            mi = m.mass[i]
            gi = mi * (x[i] - self.y[i])
            diag = mi * ti.Matrix.identity(float, 3)
            for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                s = m.adj_spring[e]
                if s >= 0:
                    gi += self.spring_grad[s]
                else:
                    gi -= self.spring_grad[-s - 1]
                if ti.static(with_hessian):
                    diag += self.spring_hess[s if s >= 0 else -s - 1]
            nrm = self.normal[i]
            if not self._free(i):
                gi = ti.Vector.zero(float, 3)
            elif ti.static(self.terrain.has_contact):
                lam_old = self.lam[i]
                lam_new = ti.cast(0.0, float)
                if self.active[i]:
                    lam_new = gi.dot(nrm)
                    if lam_new < 0:
                        self.active[i] = 0  # the objective pulls it off the surface: release
                        lam_new = 0.0
                self.lam[i] = lam_new
                fh = ti.Matrix.zero(float, 3, 3)
                if lam_old > 0 or lam_new > 0:
                    # The friction term's weight goes from lam_old to lam_new (the term is linear
                    # in lam): correct the objective at x, then add the term's derivatives.
                    f0, fg, fh1 = self._friction(i, x[i], nrm, 1.0)
                    self.sc[_F_CUR] += (lam_new - lam_old) * f0
                    gi += lam_new * fg
                    fh = lam_new * fh1
                self.fric_hess[i] = fh
                if ti.static(with_hessian):
                    diag += fh
            r = -gi
            if ti.static(self.terrain.has_contact):
                if self.active[i]:
                    r -= nrm.dot(r) * nrm
            self.grad[i] = gi
            self.rhs[i] = r
            self.sc[_RES2] += r.dot(r) * m.inv_mass[i]
            self.sc[_N_ACTIVE] += ti.cast(self.active[i], float)
            if ti.static(with_hessian):
                pinv = ti.Matrix.zero(float, 3, 3)
                if self._free(i):
                    if ti.static(self.terrain.has_contact):
                        if self.active[i]:
                            # S D S + N N^T: the constrained block, kept invertible; its inverse
                            # maps the tangent plane to itself, so PCG stays in that subspace.
                            sp = ti.Matrix.identity(float, 3) - nrm.outer_product(nrm)
                            diag = sp @ diag @ sp + nrm.outer_product(nrm)
                    pinv = diag.inverse()
                    if ti.static(self.terrain.has_contact):
                        if self.active[i]:
                            sp = ti.Matrix.identity(float, 3) - nrm.outer_product(nrm)
                            pinv = sp @ pinv @ sp
                self.precond[i] = pinv

    @ti.func
    def _trial(self, x: ti.template(), dt, alpha):
        """x_trial = x + alpha dx, made feasible; the objective there and grad . (x_trial - x).

        Constrained particles are put back onto the surface (its normal may turn along a curved
        terrain), others are projected out if they end inside; the contact flags of the trial
        point go to ``trial_active``/``trial_normal``.
        """
        m = self.model
        h = dt
        self.sc[_F_TRIAL] = 0.0
        self.sc[_DEC] = 0.0
        for i in range(self.n):
            xi = x[i] + alpha * self.dx[i]
            hit = self.active[i]
            nrm = self.normal[i]
            if ti.static(self.terrain.has_contact):
                if self._free(i):
                    dist, nq = self.terrain.query(i, xi)
                    if hit or dist < 0:
                        xi -= dist * nq
                        hit = 1
                        nrm = nq
            self.x_trial[i] = xi
            self.trial_active[i] = hit
            self.trial_normal[i] = nrm
            diff = xi - self.y[i]
            self.sc[_F_TRIAL] += 0.5 * m.mass[i] * diff.dot(diff) * ti.cast(self._free(i), float)
            if ti.static(self.terrain.has_contact):
                if self.lam[i] > 0:  # held at the last gradient, hence held here too
                    fe, fg_unused, fh_unused = self._friction(i, xi, nrm, self.lam[i])
                    self.sc[_F_TRIAL] += fe
            self.sc[_DEC] += self.grad[i].dot(xi - x[i])
        for s in range(m.n_springs):
            a, b = m.spring_ends[s][0], m.spring_ends[s][1]
            grp = m.spring_group[s]
            u = (self.x_trial[a] - self.x_prev[a]) - (self.x_trial[b] - self.x_prev[b])
            lu = self.spring_dir[s].dot(u)
            self.sc[_F_TRIAL] += h * h * spring_energy(m, self.x_trial, a, b, m.spring_rest[s], grp) \
                + 0.5 * h * m.group_kd[grp] * lu * lu

    @ti.func
    def _accept_trial(self, x: ti.template()):
        for i in range(self.n):
            x[i] = self.x_trial[i]
            self.active[i] = self.trial_active[i]
            self.normal[i] = self.trial_normal[i]
        self.sc[_F_CUR] = self.sc[_F_TRIAL]

    @ti.func
    def _end_step(self, x: ti.template(), v: ti.template(), dt, step):
        """v = (x - x_n)/h, then restitution for constrained particles; _finish."""
        for i in range(self.n):
            xn = x[i]
            vn = (xn - self.x_prev[i]) / dt
            if ti.static(self.terrain.has_contact):
                if self.active[i] and self._free(i):
                    nrm = self.normal[i]
                    # The constraint absorbed the approach velocity; hand Terrain.respond the
                    # pre-impact normal velocity so it reflects that with restitution, as it does
                    # for the explicit methods.
                    approach = nrm.dot(self.v_prev[i])
                    if approach < 0 and approach < nrm.dot(vn):
                        vn += (approach - nrm.dot(vn)) * nrm
            self._finish(i, x, v, xn, vn, step)

    @ti.func
    def _residual(self):
        """Residual [m/s^2]: sqrt(sum_i |r_i|^2 / m_i / sum_i m_i) / h^2, the mass-weighted RMS of
        the unbalanced force per unit mass, M^{-1} r / h^2.

        r is the gradient with constraint-normal components removed, so it measures the KKT
        residual. Measured as an acceleration it means the same at every step size (a tolerance
        in metres would stop Newton before its first iteration at small h).
        """
        return ti.sqrt(self.sc[_RES2] / self.total_mass) / self.h2[None]

    @ti.func
    def _record(self, k):
        if k < RES_HISTORY:
            self.res_history[k] = self._residual()
        self.n_history[None] = ti.min(k + 1, RES_HISTORY)

    @ti.func
    def _step_body(self, x: ti.template(), v: ti.template(), dt, step):
        self._begin_step(x, v, dt)
        self._solve_step(x, dt)
        self._end_step(x, v, dt, step)

    # -- Python-side entry points (parallel mode; also used by tests) --------------------------
    @ti.kernel
    def _k_begin(self, x: ti.template(), v: ti.template(), dt: float):
        self._begin_step(x, v, dt)

    @ti.kernel
    def _k_gradient(self, x: ti.template(), dt: float):
        self._gradient(x, dt, True)

    @ti.kernel
    def _k_gradient_only(self, x: ti.template(), dt: float):
        self._gradient(x, dt, False)

    @ti.kernel
    def _k_trial(self, x: ti.template(), dt: float, alpha: float):
        self._trial(x, dt, alpha)

    @ti.kernel
    def _k_accept(self, x: ti.template()):
        self._accept_trial(x)

    @ti.kernel
    def _k_end(self, x: ti.template(), v: ti.template(), dt: float, step: ti.i32):
        self._end_step(x, v, dt, step)

    @ti.kernel
    def _k_account(self, outer: ti.i32, cg: ti.i32, ls: ti.i32):
        self._accumulate(outer, cg, ls)

    @ti.func
    def _accumulate(self, outer, cg, ls):
        self.acc[_A_STEPS] += 1.0
        self.acc[_A_OUTER] += ti.cast(outer, ti.f64)
        self.acc[_A_CG] += ti.cast(cg, ti.f64)
        self.acc[_A_LS] += ti.cast(ls, ti.f64)
        self.acc[_A_RES] += ti.cast(self._residual(), ti.f64)

    def residual(self) -> float:
        """Residual [m/s^2] of the last gradient evaluation (see ``_residual``)."""
        return float(np.sqrt(max(float(self.sc[_RES2]), 0.0) / self.total_mass)) / float(self.h2[None])

    def objective(self, state, dt: float) -> float:
        """g(x) [kg m^2] at ``state.x`` for the step that started at the last ``begin`` (tests)."""
        self.dx.fill(0)
        self._k_trial(state.x, dt, 0.0)
        return float(self.sc[_F_TRIAL])

    def residual_history(self) -> list[float]:
        """Residual [m/s^2] after 0, 1, 2, ... iterations of the last step."""
        return self.res_history.to_numpy()[: int(self.n_history[None])].tolist()

    # -- public API -------------------------------------------------------------------------
    def advance(self, state, dt: float, n_steps: int) -> int:
        self.tol2[None] = (self._tol() * dt * dt) ** 2 * self.total_mass
        self._prepare(dt)
        if self._serial() or n_steps <= 0 or self.diverged:
            return super().advance(state, dt, n_steps)
        start = self._step_counter
        for k in range(n_steps):
            self._k_begin(state.x, state.v, dt)
            self._solve_step_python(state, dt)
            self._k_end(state.x, state.v, dt, start + k)
            if self.contacts is not None:
                self._k_body_contacts(state.x, state.v, dt)
            if self.diverged:
                break
        self._step_counter += n_steps
        bad = int(self.diverged_step[None])
        return bad - start + 1 if self.diverged else n_steps

    def reset(self):
        super().reset()
        self.acc.fill(0)
        self.n_history[None] = 0

    def _prepare(self, dt: float):
        """Hook run before each ``advance`` with its dt [s] (fast mass-spring refactorises here)."""

    def _tol(self) -> float:
        return 0.0

    def _take_stats(self) -> list:
        a = [float(c) for c in self.acc.to_numpy()]
        self.acc.fill(0)
        return a


@register
@ti.data_oriented
class ImplicitEuler(ImplicitIntegrator):
    """Backward Euler by Newton's method on g(x), matrix-free PCG, Armijo backtracking."""

    name = "implicit_euler"
    description = "backward Euler: Newton + block-Jacobi PCG on the step's energy, line search (stable at frame-sized steps)"
    OPTIONS = {
        **Integrator.OPTIONS,
        **_CONTACT_OPTIONS,
        "newton_iters": (8, _int_at_least(1), "an integer >= 1 (most Newton iterations per step)"),
        "newton_tol": (0.1, _number_in(0.0, 1e3), "a number in [0, 1000] (residual in m/s^2 at which Newton stops)"),
        "cg_iters": (200, _int_at_least(1), "an integer >= 1 (most CG iterations per Newton iteration)"),
        "cg_tol": (1e-2, _number_in(0.0, 1.0, lo_open=True), "a number in (0, 1] (relative CG residual)"),
        "line_search_iters": (12, _int_at_least(0), "an integer >= 0 (most step halvings per Newton iteration)"),
    }

    def __init__(self, model, terrain, options=None):
        super().__init__(model, terrain, options)
        o = self.options
        m = max(model.n_springs, 1)
        self.spring_hess = ti.Matrix.field(3, 3, float, m)  # h^2 (PSD spring Hessian) + h kd l l^T
        self.precond = ti.Matrix.field(3, 3, float, self.n)  # inverse 3x3 diagonal blocks
        self.pcg = PCG(self.n)
        self.pcg.rel_tol[None] = o["cg_tol"]
        self.newton_iters = ti.field(ti.i32, ())
        self.cg_iters = ti.field(ti.i32, ())
        self.ls_iters = ti.field(ti.i32, ())
        self.newton_iters[None] = o["newton_iters"]
        self.cg_iters[None] = o["cg_iters"]
        self.ls_iters[None] = o["line_search_iters"]

    def _tol(self):
        return self.options["newton_tol"]

    # PCG operator: the filtered Hessian H = M + h^2 K_psd + h D, applied per particle by
    # gathering its springs' blocks (no atomics, no assembled matrix).
    @ti.func
    def apply(self, src: ti.template(), dst: ti.template()):
        m = self.model
        for i in range(self.n):
            q = m.mass[i] * src[i]
            for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                s = m.adj_spring[e]
                q += self.spring_hess[s if s >= 0 else -s - 1] @ (src[i] - src[m.adj_other[e]])
            if ti.static(self.terrain.has_contact):
                q += self.fric_hess[i] @ src[i]
            if not self._free(i):
                q = ti.Vector.zero(float, 3)
            elif ti.static(self.terrain.has_contact):
                if self.active[i]:
                    q -= self.normal[i].dot(q) * self.normal[i]
            dst[i] = q

    @ti.func
    def precondition(self, src: ti.template(), dst: ti.template()):
        for i in range(self.n):
            dst[i] = self.precond[i] @ src[i]

    @ti.func
    def _armijo(self):
        """Sufficient decrease (c = 1e-4), with the objective's round-off tolerated."""
        f0 = self.sc[_F_CUR]
        return self.sc[_F_TRIAL] - f0 <= 1e-4 * self.sc[_DEC] + self.roundoff[None] * ti.abs(f0)

    @ti.func
    def _solve_step(self, x: ti.template(), dt):
        for i in range(self.n):
            self.dx[i] = ti.Vector.zero(float, 3)
        self._trial(x, dt, 0.0)
        self.sc[_F_CUR] = self.sc[_F_TRIAL]
        newton = 0
        cg = 0
        backtracks = 0
        max_newton = self.newton_iters[None]
        for k in range(max_newton + 1):
            self._gradient(x, dt, True)
            self._record(k)
            if self.sc[_RES2] <= self.tol2[None] or k == max_newton:
                break
            self.pcg.solve(self, self.rhs, self.dx, self.cg_iters[None])
            cg += self.pcg.iters[None]
            newton += 1
            alpha = ti.cast(1.0, float)
            accepted = 0
            for _ in range(self.ls_iters[None] + 1):
                self._trial(x, dt, alpha)
                if self._armijo():
                    accepted = 1
                    break
                alpha *= 0.5
                backtracks += 1
            if accepted == 0:
                break  # no decrease along this direction (round-off level): x and grad stay valid
            self._accept_trial(x)
        self._accumulate(newton, cg, backtracks)

    @ti.kernel
    def _k_apply(self, src: ti.template(), dst: ti.template()):
        self.apply(src, dst)

    def _solve_step_python(self, state, dt):
        x = state.x
        self.dx.fill(0)
        self._k_trial(x, dt, 0.0)
        self.sc[_F_CUR] = self.sc[_F_TRIAL]
        newton = cg = backtracks = 0
        max_newton = self.options["newton_iters"]
        for k in range(max_newton + 1):
            self._k_gradient(x, dt)
            if k < RES_HISTORY:
                self.res_history[k] = self.residual()
                self.n_history[None] = k + 1
            if self.sc[_RES2] <= self.tol2[None] or k == max_newton:
                break
            cg += self.pcg.solve_parallel(self, self.rhs, self.dx, self.options["cg_iters"])
            newton += 1
            alpha, accepted = 1.0, False
            for _ in range(self.options["line_search_iters"] + 1):
                self._k_trial(x, dt, alpha)
                f0 = float(self.sc[_F_CUR])
                if float(self.sc[_F_TRIAL]) - f0 <= 1e-4 * float(self.sc[_DEC]) + float(self.roundoff[None]) * abs(f0):
                    accepted = True
                    break
                alpha *= 0.5
                backtracks += 1
            if not accepted:
                break
            self._k_accept(x)
        self._k_account(newton, cg, backtracks)

    def stats(self) -> dict:
        """Averages per step since the last call (or reset): Newton and CG iterations, line-search
        halvings, and the final residual [m/s^2] (see ``_residual``)."""
        a = self._take_stats()
        steps = max(a[_A_STEPS], 1.0)
        return {
            "steps": int(a[_A_STEPS]),
            "newton_iterations_per_step": a[_A_OUTER] / steps,
            "cg_iterations_per_step": a[_A_CG] / steps,
            "cg_iterations_per_newton": a[_A_CG] / max(a[_A_OUTER], 1.0),
            "line_search_halvings_per_step": a[_A_LS] / steps,
            "final_residual_m_s2": a[_A_RES] / steps,
        }


@register
@ti.data_oriented
class FastMassSpring(ImplicitIntegrator):
    """Local/global solver of Liu et al. 2013 on the same objective, prefactorised global matrix."""

    name = "fast_mass_spring"
    description = "fast mass-spring (Liu et al. 2013): local/global iterations, prefactored constant matrix"
    OPTIONS = {
        **Integrator.OPTIONS,
        **_CONTACT_OPTIONS,
        "iterations": (10, _int_at_least(1), "an integer >= 1 (local/global iterations per step)"),
        "tol": (0.0, _number_in(0.0, 1e3), "a number in [0, 1000] (residual in m/s^2 at which iterations stop early; 0 = never)"),
        "global_solver": ("auto", lambda v: v in ("auto", "cholesky", "pcg"),
                          "auto, cholesky (PCG preconditioned by the prefactored skyline Cholesky) or pcg "
                          "(matrix-free, Jacobi preconditioner)"),
        "cg_iters": (200, _int_at_least(1), "an integer >= 1 (most CG iterations per global step)"),
        "cg_tol": (0.1, _number_in(0.0, 1.0, lo_open=True), "a number in (0, 1] (relative CG residual of a global step)"),
    }

    def __init__(self, model, terrain, options=None):
        super().__init__(model, terrain, options)
        o = self.options
        solver = o["global_solver"]
        if solver == "auto":
            # The triangular solves are serial: the Cholesky wins on a CPU, PCG on a GPU. Its
            # envelope grows like N^(5/3) for a cube (N particles), factorising like N^(7/3): past
            # CHOLESKY_AUTO_MAX values (the 20^3 cube has 6.4e6; the 40^3 one 2e8, 1.6 GB in f64
            # and an hour-long factorisation) auto takes PCG.
            cpu = ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64)
            small = SkylineCholesky.envelope_size(self.n, model.pairs_np) <= CHOLESKY_AUTO_MAX
            solver = "cholesky" if cpu and small else "pcg"
        self.global_solver = solver
        self.group_c = ti.field(float, model.n_groups)  # Laplacian weight h^2 k + h kd [kg]
        self.diag = ti.field(float, self.n)  # diagonal of M + L (PCG's Jacobi preconditioner)
        self.iterations = ti.field(ti.i32, ())
        self.iterations[None] = o["iterations"]
        self.cg_iters = ti.field(ti.i32, ())
        self.cg_iters[None] = o["cg_iters"]
        if solver == "cholesky":
            self.chol = SkylineCholesky(self.n, model.pairs_np)
        self.pcg = PCG(self.n)
        self.pcg.rel_tol[None] = o["cg_tol"]
        self._matrix_key = None
        self.factorizations = 0

    def _tol(self):
        return self.options["tol"]

    # -- the constant global matrix A = M + L, L with weights c_s = h^2 k_s + h kd_s -------------
    def _prepare(self, dt: float):
        """(Re)build the global matrix when dt, a stiffness, a damper coefficient or a mass changed."""
        key = (float(dt), self.model.group_k.to_numpy().tobytes(), self.model.group_kd.to_numpy().tobytes(),
               self.model.mass_version)
        if key == self._matrix_key:
            return
        self._k_weights(dt)
        if self.global_solver == "cholesky":
            self._k_assemble()
            self.chol.factor()
            if not self.chol.ok[None]:
                raise FloatingPointError("fast_mass_spring: global matrix is not positive definite (negative stiffness?)")
        self._matrix_key = key
        self.factorizations += 1

    @ti.kernel
    def _k_weights(self, dt: float):
        m = self.model
        for g in range(m.n_groups):
            self.group_c[g] = dt * dt * m.group_k[g] + dt * m.group_kd[g]
        for i in range(self.n):
            d = m.mass[i]
            for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                d += self.group_c[m.adj_group[e]]
            self.diag[i] = d if self._free(i) else 0.0

    @ti.kernel
    def _k_assemble(self):
        m = self.model
        self.chol.clear()
        for i in range(self.n):
            # Pinned rows become identity rows: their correction is zero (Dirichlet).
            self.chol.add(i, i, self.diag[i] if self._free(i) else 1.0)
        for s in range(m.n_springs):
            a, b = m.spring_ends[s][0], m.spring_ends[s][1]
            if self._free(a) and self._free(b):
                self.chol.add(ti.max(a, b), ti.min(a, b), -self.group_c[m.spring_group[s]])

    # The global step's linear system, filtered by the contact constraints: A dx = rhs with the
    # normal component of dx fixed to 0 for particles held on the terrain (as in the Newton
    # solve). PCG preconditioned by the prefactored Cholesky of the unconstrained A solves it in
    # one iteration when nothing is in contact, and in a few when the constraints perturb A by
    # a low-rank change; without the Cholesky, Jacobi-preconditioned PCG is the fallback.
    @ti.func
    def _filter(self, i, q):
        out = q
        if not self._free(i):
            out = ti.Vector.zero(float, 3)
        elif ti.static(self.terrain.has_contact):
            if self.active[i]:
                out = q - self.normal[i].dot(q) * self.normal[i]
        return out

    @ti.func
    def apply(self, src: ti.template(), dst: ti.template()):
        m = self.model
        for i in range(self.n):
            q = self.diag[i] * src[i]
            for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                q -= self.group_c[m.adj_group[e]] * src[m.adj_other[e]]
            if ti.static(self.terrain.has_contact):
                q += self.fric_hess[i] @ src[i]  # friction of held particles (not in the factorisation)
            dst[i] = self._filter(i, q)

    @ti.func
    def precondition(self, src: ti.template(), dst: ti.template()):
        if ti.static(self.global_solver == "cholesky"):
            self.chol.solve(src, dst)
            for i in range(self.n):
                dst[i] = self._filter(i, dst[i])
        else:
            for i in range(self.n):
                dst[i] = self._filter(i, src[i] / ti.max(self.diag[i], 1e-300))

    @ti.func
    def _global_step(self, x: ti.template()):
        """x += dx, then project what ended inside the terrain onto its surface (and hold it)."""
        for i in range(self.n):
            xi = x[i] + self.dx[i]
            if ti.static(self.terrain.has_contact):
                if self._free(i):
                    dist, nrm = self.terrain.query(i, xi)
                    if dist < 0 or self.active[i]:
                        xi -= dist * nrm
                        self.active[i] = 1
                        self.normal[i] = nrm
            x[i] = xi

    @ti.func
    def _solve_step(self, x: ti.template(), dt):
        iters = self.iterations[None]
        done = 0
        cg = 0
        for k in range(iters + 1):
            # Local step (inside the gradient): d_s = r_s l_s for every spring, w_s = the damper
            # displacement projected normal to l_s; then rhs = (M y + B d + ...) - A x = -grad g.
            self._gradient(x, dt, False)
            self._record(k)
            if self.sc[_RES2] <= self.tol2[None] or k == iters:
                break
            if ti.static(self.global_solver == "cholesky"):
                if self.sc[_N_ACTIVE] == 0:
                    self.chol.solve(self.rhs, self.dx)  # no constraints: the factorisation is exact
                else:
                    self.pcg.solve(self, self.rhs, self.dx, self.cg_iters[None])
                    cg += self.pcg.iters[None]
            else:
                self.pcg.solve(self, self.rhs, self.dx, self.cg_iters[None])
                cg += self.pcg.iters[None]
            self._global_step(x)
            done += 1
        self._accumulate(done, cg, 0)

    @ti.kernel
    def _k_global_step(self, x: ti.template()):
        self._global_step(x)

    def _solve_step_python(self, state, dt):
        x = state.x
        iters = self.options["iterations"]
        done = cg = 0
        for k in range(iters + 1):
            self._k_gradient_only(x, dt)
            if k < RES_HISTORY:
                self.res_history[k] = self.residual()
                self.n_history[None] = k + 1
            if self.sc[_RES2] <= self.tol2[None] or k == iters:
                break
            if self.global_solver == "cholesky" and self.sc[_N_ACTIVE] == 0:
                self.chol.solve_kernel(self.rhs, self.dx)
            else:
                cg += self.pcg.solve_parallel(self, self.rhs, self.dx, self.options["cg_iters"])
            self._k_global_step(x)
            done += 1
        self._k_account(done, cg, 0)

    def stats(self) -> dict:
        """Averages per step since the last call (or reset): local/global iterations, CG
        iterations (pcg global solver), final residual [m/s^2]; the global solver and how often the
        matrix was factorised (or rebuilt) so far."""
        a = self._take_stats()
        steps = max(a[_A_STEPS], 1.0)
        out = {
            "steps": int(a[_A_STEPS]),
            "local_global_iterations_per_step": a[_A_OUTER] / steps,
            "final_residual_m_s2": a[_A_RES] / steps,
            "global_solver": self.global_solver,
            "factorizations": self.factorizations,
        }
        out["cg_iterations_per_step"] = a[_A_CG] / steps
        return out
