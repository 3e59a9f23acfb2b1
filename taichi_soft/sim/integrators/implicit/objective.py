"""The step's objective: inertia, springs, dampers and contact friction, its gradient and values.

    g(x) = 1/2 (x - y)^T M (x - y) + h^2 E(x) + h^2 D(x) + sum_held mu lam_i f0(|u_t,i|) [+ grab]
    y = x_n + h v_n + h^2 g_grav,  u = x - x_n

E: Hooke springs, sum_s k_s/2 (|x_a - x_b| - r_s)^2. D: the dampers' Rayleigh dissipation with
each damper direction l_s frozen at x_n, h^2 D = sum_s h kd_s/2 (l_s . (u_a - u_b))^2 (its
gradient / h^2 is the seed's damper force at v = u/h). Friction: the lagged dissipative potential
of IPC (Li et al. 2020) with each held particle's multiplier lam_i (h^2 |F_n|) frozen for the
solve (see contact.py); f0 is the Huber function with length friction_velocity * h.
With ``solver.scheme = "bdf2"`` (scheme.py) a step may be BDF2: h is then h_e = 2h/3, y is BDF2's
target and the dampers and friction measure u - u_base (x - x^, h_e times the end velocity). A model with
a grab (grab.py) adds its spring (counted in E) and damper for the grabbed particle.

Every term is zero or minimal at x_n except inertia and springs, and the friction term is zero at
x_n for any multiplier, so g(x) <= g(x_n) bounds the energy a step can store whatever the
multipliers are (docs/implicit.md).
"""

import taichi as ti

from ...allocation import allocate
from ...footprint import MAT, VEC, per_particle, per_spring
from ...forces import spring_energy, spring_energy_derivatives
from ...model import code_spring, end_b_spring, is_end_a
from .operator import require


@ti.func
def lagged_friction(disp, nrm, c, eps):
    """Lagged Coulomb friction of a displacement ``disp`` [m] against a contact of normal ``nrm``:
    (energy [kg m^2], gradient [kg m], Hessian [kg]) of c f0(|u_t|), u_t = (I - N N^T) disp,
    c = mu lam [kg m] (lam = h^2 |F_n| frozen), f0 the Huber function: quadratic below ``eps`` =
    friction_velocity * h [m], linear beyond. The terrain's contacts (contact.py) and the
    pairs between bodies (pairs.py) both use it."""
    tp = ti.Matrix.identity(float, 3) - nrm.outer_product(nrm)
    u = tp @ disp
    sl = u.norm()
    energy = ti.cast(0.0, float)
    grad = ti.Vector.zero(float, 3)
    hess = ti.Matrix.zero(float, 3, 3)
    if sl < eps:
        energy = 0.5 * c * sl * sl / eps
        grad = (c / eps) * u
        hess = (c / eps) * tp
    else:
        energy = c * (sl - 0.5 * eps)
        grad = (c / sl) * u
        hess = (c / sl) * tp
    return energy, grad, hess


@ti.data_oriented
class Objective:
    """The step's objective g, its gradient and its values: a part of ``ImplicitIntegrator``.

    Given at construction: the ``model``, the ``terrain``, the step's scalars ``sc`` (scalars.py),
    the ``scheme`` (scheme.py: u_base, the step's base), the terrain ``contact`` (contact.py: the
    active set and friction) and the ``operator`` (operator.LinearOperator: the solver's linear
    operator, which the gradient pass fills through ``store_spring_hessian(s, block)`` and
    ``store_preconditioner(i)``, and asks ``grab_factored(i)``). ``pairs`` (pairs.PairContacts) is given by the solver when it builds its
    body-body pairs, before any kernel compiles; None: a scene of one body, no pair code.

    Holds the step's start (x_n, v_n, the target yd), its iterate u with the search direction dx
    and the line-search trial, and what the gradient pass leaves (grad, rhs, fric_hess): the
    driver's phases and the direction read and write them. Writes the objective's members of
    ``sc``: res2, n_active, n_pairs, lam_change, lam_sum (gradient); f_trial, e_trial, dec,
    step_trial (trial).
    """

    # The solve iterates on displacements from x_n (u, u_trial, yd): in f32 a position near 9 m
    # rounds to 1e-6 m, as much as a 1 ms step's motion changes per step, and the rounding was
    # biased (free fall 2.6 % slow at 1 ms). The objective's inertia and damper terms and the
    # step's velocity read these; positions (springs, terrain) are x_n + u.
    BUFFERS = {
        "x_prev": per_particle("x_n [m]", VEC),
        "v_prev": per_particle("v_n [m/s]", VEC),
        "u": per_particle("displacement x - x_n of the current iterate [m]", VEC),
        "u_trial": per_particle("displacement of the line-search trial point [m]", VEC),
        "yd": per_particle("the inertial target y as a displacement: y - x_n = h v_n + h^2 g [m]", VEC),
        "grad": per_particle("gradient of the objective [kg m]", VEC),
        "rhs": per_particle("-grad with held particles' normal components removed [kg m]", VEC),
        "dx": per_particle("update direction of the current iteration [m]", VEC),
        "x_trial": per_particle("line-search trial point [m]", VEC),
        # a held particle's friction, the grab (grab.py): not in fast_mass_spring's constant matrix
        "fric_hess": per_particle("Hessian block of a particle's terms outside the springs [kg]", MAT),
        "spring_dir": per_spring("damper direction l_s at x_n (frozen over the step)", VEC),
        "spring_grad": per_spring("d(h^2 (E + D))/dx_a per spring [kg m]", VEC),
    }

    def __init__(self, model, terrain, sc, scheme, contact, operator):
        """Allocates the fields only (no write: the owner's pending SNode tree stays open; the
        owner sets the values once every field is allocated)."""
        self.model, self.terrain, self.sc, self.scheme, self.contact = model, terrain, sc, scheme, contact
        self.operator = require(operator)
        self.pairs = None
        self.n = model.n_particles
        allocate(self, self.BUFFERS, self.n, model.n_springs)
        self.fric_eps = ti.field(float, ())  # friction smoothing length friction_velocity * h [m]
        self.friction_velocity = ti.field(float, ())  # [m/s], from the option (a field: read in kernels)
        self.total_mass = ti.field(float, ())  # sum of free particles' masses [kg] (see _sync_masses)
        self.h2 = ti.field(float, ())  # h^2 of the current step [s^2]
        # 1: nothing but inertia depends on where the whole system is (no terrain, nothing pinned),
        # so the step can minimise g exactly over rigid translations (``translation_minimum``)
        self.translation_free = ti.field(ti.i32, ())
        self.shift = ti.Vector.field(3, float, ())  # that translation [m]

    def _has_pairs(self) -> bool:
        return self.pairs is not None

    @ti.func
    def filter(self, i, q):
        """q with what particle i cannot move removed: all of it if pinned, the normal component
        if held on the terrain (Baraff & Witkin 1998, Sec. 5.3)."""
        out = q
        if not self.model.free(i):
            out = ti.Vector.zero(float, 3)
        elif ti.static(self.terrain.has_contact):
            out = self.contact.filter(i, q)
        return out

    @ti.func
    def filtered_inverse(self, i, block):
        """Inverse of particle i's diagonal 3x3 ``block`` as a block-Jacobi preconditioner uses it:
        0 if pinned; if held on the terrain, S (S B S + N N^T)^-1 S (S = I - N N^T: the constrained
        block, kept invertible; its inverse maps the tangent plane to itself, so PCG stays there)."""
        pinv = ti.Matrix.zero(float, 3, 3)
        if self.model.free(i):
            held = 0
            if ti.static(self.terrain.has_contact):
                held = self.contact.active[i]
            if held:
                nrm = self.contact.normal[i]
                sp = ti.Matrix.identity(float, 3) - nrm.outer_product(nrm)
                pinv = sp @ (sp @ block @ sp + nrm.outer_product(nrm)).inverse() @ sp
            else:
                pinv = block.inverse()
        return pinv

    @ti.func
    def from_base(self, i, xi):
        """Particle i's displacement from the step's base, xi - x_n - u_base [m] (h_e times its end
        velocity: what the dampers and friction measure)."""
        return xi - self.x_prev[i] - self.scheme.u_base[i]

    @ti.func
    def spring_terms(self, x: ti.template(), s, dt):
        """(gradient of h^2 (E + D) w.r.t. end a [kg m], h^2 E_s Hessian block + h kd l l^T [kg])."""
        m = self.model
        a, b = m.spring_ends[s][0], m.spring_ends[s][1]
        grp = m.spring_group[s]
        ge, he = spring_energy_derivatives(m, x, a, b, m.spring_rest[s], grp)
        l = self.spring_dir[s]
        ub = ti.static(self.scheme.u_base)
        u = (self.u[a] - ub[a]) - (self.u[b] - ub[b])  # h_e times the end velocity
        kd = m.group_kd[grp]
        return dt * dt * ge + (dt * kd * l.dot(u)) * l, dt * dt * he + (dt * kd) * l.outer_product(l)

    @ti.func
    def gradient(self, x: ti.template(), dt):
        """grad g(x), the filtered residual ``rhs`` and its norm (``sc.res2``), from one pass over springs
        and one gather per particle. The contact active set (hold, release, multipliers) is updated
        per particle by the terrain contact part (``contact.gradient``, contact.py). The same passes
        store what the solver's linear operator needs (``store_spring_hessian``,
        ``store_preconditioner``): one pass instead of a separate Hessian phase halves the serial
        kernel's compile time."""
        m = self.model
        for s in range(m.n_springs):
            g, hs = self.spring_terms(x, s, dt)
            self.spring_grad[s] = g
            self.operator.store_spring_hessian(s, hs)
        self.sc.res2[None] = 0.0
        self.sc.n_active[None] = 0.0
        self.sc.n_pairs[None] = 0.0
        self.sc.lam_change[None] = 0.0
        self.sc.lam_sum[None] = 0.0
        if ti.static(self._has_pairs()):
            self.pairs.gradient(x, self.u)  # body-body contact (pairs.py)
        for i in range(self.n):
            gi = m.mass[i] * (self.u[i] - self.yd[i])
            for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                s = m.adj_spring[e]
                if is_end_a(s):
                    gi += self.spring_grad[code_spring(s)]
                else:
                    gi -= self.spring_grad[end_b_spring(s)]
            r = ti.Vector.zero(float, 3)
            if self.model.free(i):
                if ti.static(self._has_pairs()):
                    gi += self.pairs.grad[i]
                if ti.static(self.terrain.has_contact):
                    gi, self.fric_hess[i] = self.contact.gradient(i, self.from_base(i, x[i]), gi, dt,
                                                                  self.fric_eps[None])
                if ti.static(self._has_pairs()):
                    # the pairs' diagonal blocks join the terrain friction's (just written)
                    if ti.static(self.terrain.has_contact):
                        self.fric_hess[i] += self.pairs.hess[i]
                    else:
                        self.fric_hess[i] = self.pairs.hess[i]
                if ti.static(self.model.has_grab()):
                    gi = self.grab_gradient(i, x[i], gi, dt)
                r = -gi
                if ti.static(self.terrain.has_contact):
                    if self.contact.active[i]:
                        r -= self.contact.normal[i].dot(r) * self.contact.normal[i]
                        self.sc.n_active[None] += 1.0
            else:
                gi = ti.Vector.zero(float, 3)
            self.grad[i] = gi
            self.rhs[i] = r
            self.sc.res2[None] += r.dot(r) * m.inv_mass[i]
            self.operator.store_preconditioner(i)

    @ti.func
    def trial(self, x: ti.template(), dt):
        """x_trial = x + alpha dx (alpha = ``sc.alpha``) made feasible (``contact.project``); the
        objective there (``sc.f_trial``), its spring energy, grad . (x_trial - x) and the largest move."""
        m = self.model
        alpha = self.sc.alpha[None]
        self.sc.f_trial[None] = 0.0
        self.sc.dec[None] = 0.0
        self.sc.e_trial[None] = 0.0
        self.sc.step_trial[None] = 0.0
        if ti.static(self._has_pairs()):
            self.pairs.trial_begin()
        for i in range(self.n):
            ui = self.u[i] + ti.cast(alpha, float) * self.dx[i]
            xi = self.x_prev[i] + ui
            if ti.static(self.terrain.has_contact):
                held = 0
                xi, held = self.contact.project(i, xi, alpha > 0)  # alpha = 0: the current point exactly
                if held:  # on the surface: the displacement to the projected point
                    ui = xi - self.x_prev[i]
            self.x_trial[i] = xi
            self.u_trial[i] = ui
            if self.model.free(i):
                if ti.static(self._has_pairs()):
                    self.pairs.track(i, ui)  # the trust region
                diff = ui - self.yd[i]
                self.sc.f_trial[None] += 0.5 * m.mass[i] * diff.dot(diff)
                if ti.static(self.model.has_grab()):
                    gv, _gg, _gh = m.grab.step_terms(i, xi, self.x_prev[i], dt)
                    self.sc.f_trial[None] += gv
                    self.sc.e_trial[None] += m.grab.energy(i, xi)  # counted with the springs' energy
                if ti.static(self.terrain.has_contact):
                    if self.contact.frozen(i):
                        self.sc.f_trial[None] += self.contact.trial_friction(i, self.from_base(i, xi),
                                                                             self.fric_eps[None])
            move = xi - x[i]
            self.sc.dec[None] += self.grad[i].dot(move)
            ti.atomic_max(self.sc.step_trial[None], move.norm())
        for s in range(m.n_springs):
            a, b = m.spring_ends[s][0], m.spring_ends[s][1]
            grp = m.spring_group[s]
            ub = ti.static(self.scheme.u_base)
            u = (self.u_trial[a] - ub[a]) - (self.u_trial[b] - ub[b])
            lu = self.spring_dir[s].dot(u)
            es = spring_energy(m, self.x_trial, a, b, m.spring_rest[s], grp)
            self.sc.e_trial[None] += es
            self.sc.f_trial[None] += dt * dt * es + 0.5 * dt * m.group_kd[grp] * lu * lu
        if ti.static(self._has_pairs()):
            self.pairs.trial_end(self.x_trial, self.u_trial, dt)

    @ti.func
    def translation_minimum(self, x: ti.template()):
        """Move x by the rigid translation that minimises g exactly (free space only, see
        ``translation_free``): springs, dampers and body-body pairs are invariant under it, so it is
        the one that zeroes sum_i m_i (x_i - y_i), i.e. the step conserves linear momentum exactly
        however early the iteration stopped (an inexact solve leaves a momentum error of the order of
        its residual; between colliding bodies it was 5e-4 of a body's momentum). It only lowers g.
        Returns 1 if it moved x (the residual ``sc.res2`` then is the moved state's), else 0."""
        m = self.model
        free = self.translation_free[None]
        if ti.static(m.has_grab()):
            if m.grab.active():  # a hand holds a particle at a point: not invariant
                free = 0
        if free:
            self.shift[None] = ti.Vector.zero(float, 3)
            for i in range(self.n):
                self.shift[None] += m.mass[i] * (self.yd[i] - self.u[i])
            c = self.shift[None] / self.total_mass[None]
            for i in range(self.n):
                self.u[i] += c
                x[i] = self.x_prev[i] + self.u[i]
            # The last gradient's residual, moved with the iterate (so the reported residual is the
            # returned state's): springs, dampers and pairs sum to zero over the bodies, so
            # sum_i g_i = -M c, and sum_i |g_i + m_i c|^2 / m_i = res2 - M |c|^2 exactly.
            self.sc.res2[None] = ti.max(self.sc.res2[None] - self.total_mass[None] * c.dot(c), 0.0)
        return free

    @ti.func
    def grab_gradient(self, i, xi, gi, dt):
        """gi plus the grab's gradient (grab.py); its Hessian goes with the friction block. While
        particle i is grabbed it counts in ``sc.n_active`` unless the solver's matrix carries the grab
        (``grab_factored``): a matrix that lacks the grab's diagonal term takes the held-particle
        path (the factor as a preconditioner), as for a particle held by friction."""
        _gv, gg, gh = self.model.grab.step_terms(i, xi, self.x_prev[i], dt)
        fh = ti.Matrix.zero(float, 3, 3)
        if ti.static(self.terrain.has_contact or self._has_pairs()):
            fh = self.fric_hess[i]  # this gradient's friction and pair blocks (written just before)
        self.fric_hess[i] = fh + gh * ti.Matrix.identity(float, 3)
        if gh > 0 and not self.operator.grab_factored(i):
            self.sc.n_active[None] += 1.0
        return gi + gg

    @ti.func
    def residual(self):
        """Residual [m/s^2]: sqrt(sum_i |r_i|^2 / m_i / sum_i m_i) / h^2, the mass-weighted RMS of
        the unbalanced force per unit mass (r: the gradient with held particles' normal
        components removed, the KKT residual). An acceleration means the same at every step size."""
        return ti.sqrt(ti.max(self.sc.res2[None], 0.0) / self.total_mass[None]) / self.h2[None]
