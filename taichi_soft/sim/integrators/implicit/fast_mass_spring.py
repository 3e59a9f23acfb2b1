"""``fast_mass_spring``: the local/global solver of Liu et al. 2013 on the same objective.

E is rewritten with one auxiliary vector per spring, k/2 (|x_a - x_b| - r)^2 =
min_{|d| = r} k/2 |x_a - x_b - d|^2 (and each damper term likewise). The local step
d_s = r_s (x_a - x_b)/|x_a - x_b| happens inside the gradient pass; the global step solves the
constant system (M + L) dx = -grad g, L the graph Laplacian with weights h^2 k_s + h kd_s,
prefactorised (skyline Cholesky, ``linalg.SkylineCholesky``) and refactorised only when dt, a
stiffness, a damper coefficient or a mass changes. Under contact the global step is, by default,
one solve with that factorisation and one block-Jacobi smoothing step, filtered (held particles
keep their normal component) and scaled by the step's quadratic model
(``contact_solve = "scaled"``), or the filtered system solved by PCG preconditioned by the
factorisation (``"pcg"``); ``"auto"`` picks by the springs' stiffness at the step (fast_mass_spring_laplacian.py). The global step is a descent direction of g
(M + L is SPD), so the shared driver's line search keeps g(x_k) <= g(x_n) at every iterate, and
its stopping tests apply as for Newton.
"""

import taichi as ti

from ...footprint import MAT, Buffers, FieldCounts, per_particle
from ..base import MB, model_counts, register, running_target
from .accounts import contact_stats
from .driver import ImplicitIntegrator
from .fast_mass_spring_laplacian import LaplacianMatrix
from .fast_mass_spring_lbfgs import LBFGS_DIRECTION
from .fast_mass_spring_lbfgs import PHASES as OWN_PHASES
from .options import FastMassSpringConfig


@register
@ti.data_oriented
class FastMassSpring(ImplicitIntegrator):
    """Local/global solver of Liu et al. 2013 on the same objective, prefactorised global matrix."""

    name = "fast_mass_spring"
    description = "fast mass-spring (Liu et al. 2013): local/global iterations, prefactored constant matrix"
    Config = FastMassSpringConfig
    BUFFERS = {"jacobi_inv": per_particle("block-Jacobi inverses of a Jacobi-preconditioned solve [1/kg]", MAT)}
    FIELDS = ImplicitIntegrator.FIELDS + FieldCounts.of(LaplacianMatrix.BUFFERS)  # and its matrix's (fast_mass_spring_laplacian.py)
    BASE_BYTES = 164 * MB  # measured (memory.py): process, runtime, compiled kernels
    DIRECTION = LBFGS_DIRECTION  # L-BFGS over the global step (fast_mass_spring_lbfgs.py)
    PHASES = {**ImplicitIntegrator.PHASES, **OWN_PHASES}  # and its own (fast_mass_spring_lbfgs.py)

    @classmethod
    def buffers(cls, options, arch, counts, real_bytes):
        """Besides the shared ones: the matrix's factor (``LaplacianMatrix.buffers``) and the L-BFGS
        pairs, 6 reals per particle per pair kept (s, y) and 6 for the iterate and rhs it saves (none
        with ``history = 0``)."""
        history = options.history
        return super().buffers(options, arch, counts, real_bytes) \
            + LaplacianMatrix.buffers(options, counts, real_bytes, cls.field_counts()) \
            + Buffers(FieldCounts(6 * history + 6 if history else 0))

    def __init__(self, model, terrain, options=None, contacts=None):
        n = model.n_particles
        chosen = self.configure(options, *running_target(), model_counts(model))
        solver = chosen.global_solver
        self.global_solver = solver
        self.matrix = LaplacianMatrix(model, solver, contact_auto=chosen.contact_solve == "auto")  # A = M + L
        self.factorised = self.matrix.factorised  # a compile-time constant
        self.scaled_contact = self.factorised and chosen.contact_solve != "pcg"  # compiled in or not
        # The grab's term in the factor (Sherman-Morrison, see _factor_solve): w = A^-1 e_i for
        # the grabbed particle i, solved once per grab and factorisation.
        self.grab_in_factor = self.factorised and model.has_grab()  # a compile-time constant
        self.grab_w = ti.field(float, n) if self.grab_in_factor else None
        self.grab_w_for = ti.field(ti.i32, ())  # the particle w is for (grab.NONE: none)
        self.grab_w_for[None] = -1
        self._grab_w_key = None
        # L-BFGS within a step (fixed at construction: a compile-time constant), see fast_mass_spring_lbfgs.py.
        self.history = chosen.history
        if self.history:
            self.lb_s = ti.Vector.field(3, float, (n, self.history))  # x_{k+1} - x_k [m]
            self.lb_y = ti.Vector.field(3, float, (n, self.history))  # rhs_k - rhs_{k+1} [kg m]
            self.lb_rho = ti.field(float, self.history)  # 1 / (s . y) [1/(kg m^2)]
            self.lb_alpha = ti.field(float, self.history)  # the two-loop recursion's coefficients
            self.lb_x = ti.Vector.field(3, float, n)  # the iterate of the last direction, as u = x - x_n [m]
            self.lb_r = ti.Vector.field(3, float, n)  # its rhs [kg m]
            self.lb_dot = ti.field(float, ())
        super().__init__(model, terrain, chosen, contacts)  # resolved: nothing left to choose there

    def _prepare(self, dt: float):
        self.matrix.prepare(dt)
        if self.grab_in_factor:
            held = self.model.grab.held
            key = (held, self.matrix.factorizations)
            if key != self._grab_w_key:
                self._k_grab_column(-1 if held is None else held)
                self._grab_w_key = key

    @ti.kernel
    def _k_grab_column(self, i: ti.i32):
        """w = A^-1 e_i for the grabbed particle i (-1: none). A pinned particle's row of A is the
        identity and its grab pulls nothing, so it gets no column."""
        z = ti.static(self.pcg.z)  # free between steps
        for j in range(self.n):
            z[j] = ti.Vector.zero(float, 3)
        ok = 0
        if i >= 0:
            if self.model.free(i):
                ok = 1
        if ok:
            z[i] = ti.Vector([1.0, 1.0, 1.0])
            self.matrix.chol.solve(z, z)
            for j in range(self.n):
                self.grab_w[j] = z[j][0]
        self.grab_w_for[None] = i if ok else -1

    @ti.func
    def grab_factored(self, i):
        """Whether the grab on particle i is in the factor (_factor_solve), so it does not make
        the particle count as held."""
        out = False
        if ti.static(self.grab_in_factor):
            out = i == self.grab_w_for[None]
        return out

    @ti.func
    def _factor_solve(self, b: ti.template(), x: ti.template()):
        """x = (A + c e_i e_i^T)^-1 b: the factor's solve, with the grab on particle i (Hessian
        c I3, c = h^2 k + h c_d, grab.py) added by Sherman-Morrison,
        x = z - w (c z_i) / (1 + c w_i), z = A^-1 b, w = A^-1 e_i. Without it a stiff grab is a
        diagonal term far above the factor's (1e6 N/m at 1/30 s: 1.1e3 kg against ~40 kg), and the
        held-particle path it took reached the iteration cap at residuals of 4e4 m/s^2 for steps."""
        self.matrix.chol.solve(b, x)
        if ti.static(self.grab_in_factor):
            i = self.grab_w_for[None]
            if i >= 0:
                if i == self.model.grab.index[None]:
                    h2 = self.objective.h2[None]
                    c = h2 * self.model.grab.k[None] + ti.sqrt(h2) * self.model.grab.c[None]
                    coef = c / (1.0 + c * self.grab_w[i]) * x[i]
                    for j in range(self.n):
                        x[j] -= self.grab_w[j] * coef

    # The global step's linear system, filtered by the contact constraints: A dx = rhs with the
    # normal component of dx fixed to 0 for held particles (as in the Newton solve). With nothing
    # held the plain triangular solve is exact. With held particles, "pcg" solves the filtered
    # system by PCG preconditioned by the prefactored Cholesky of the unconstrained A (a few
    # iterations: the constraints perturb A by a low-rank change), "scaled" takes only its first
    # direction (see _scaled_direction).
    # Its linear operator (operator.LinearOperator): A + F, filtered (F the friction, pair and grab
    # blocks the gradient pass leaves in ``objective.fric_hess``).
    @ti.func
    def store_spring_hessian(self, s, hs):
        pass  # A is constant; the friction blocks come from the gradient

    @ti.func
    def store_preconditioner(self, i):
        pass  # prepared per solve (prepare_preconditioner)

    @ti.func
    def apply(self, src: ti.template(), dst: ti.template()):
        m = self.model
        mat = self.matrix
        for i in range(self.n):
            q = mat.diag[i] * src[i] + self.objective.fric_hess[i] @ src[i]  # friction: not in the factorisation
            for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                q -= mat.group_c[m.adj_group[e]] * src[m.adj_other[e]]
            dst[i] = self.objective.filter(i, q)
        if ti.static(self._has_pairs()):
            self.pairs.apply(src, dst)

    @ti.func
    def _jacobi(self):
        """1: CG is Jacobi-preconditioned now: without a factor; with one, on stiff springs
        (by_stiffness, ``matrix.jacobi_now``) and while body pairs touch (their penalty is not in the
        factor: on the pile at 1/60 s the factor-preconditioned steps took 2.2x the time of Jacobi
        ones, docs/benchmarks/IMPLICIT.md)."""
        out = 1
        if ti.static(self.factorised):
            out = self.matrix.jacobi_now[None]
            if ti.static(self._has_pairs()):
                if self.sc.n_pairs[None] > 0:
                    out = 1
        return out

    @ti.func
    def _jacobi_block(self, i):
        """Particle i's 3x3 diagonal block of A + F [kg]: A's diagonal with its friction and pair blocks."""
        return self.matrix.diag[i] * ti.Matrix.identity(float, 3) + self.objective.fric_hess[i]

    @ti.func
    def prepare_preconditioner(self):
        """The block-Jacobi inverses of this solve, when it is Jacobi-preconditioned: A's diagonal with
        the particle's friction and pair blocks, which hold the stiff terms (a pair's kappa m / h^2 is
        ~1000x the mass term), filtered for held particles."""
        jacobi = self._jacobi()
        for i in range(self.n):  # a loop under a run-time branch would run serially
            if jacobi:
                blk = self._jacobi_block(i)
                self.jacobi_inv[i] = self.objective.filtered_inverse(i, blk)

    @ti.func
    def precondition(self, src: ti.template(), dst: ti.template()):
        jacobi = self._jacobi()
        if ti.static(self.factorised):
            if not jacobi:
                self._factor_solve(src, dst)
        for i in range(self.n):  # one loop for both (a loop under a run-time branch runs serially)
            if jacobi:
                dst[i] = self.jacobi_inv[i] @ src[i]  # (prepare_preconditioner)
            else:
                dst[i] = self.objective.filter(i, dst[i])

    @ti.func
    def _scaled_direction(self):
        """The global step under contact in one factor solve: z = S A^-1 S rhs (S removes held
        particles' normal components), then one block-Jacobi smoothing step with the diagonal
        blocks of A + F (F the friction blocks, absent from the factor),
        d = z + S D^-1 (rhs - (A + F) z), and dx = alpha d with alpha minimising the step's quadratic
        model along d. Falls back to z if d is not a descent direction.

        A coarse solve plus a smoother, as a two-level method: the factor carries the springs, the
        smoother the friction of particles that stick (whose friction stiffness mu lam / eps is far
        above their mass) -- without it, on the bowl at x1 and 1/60 s the steps stalled at the
        iteration cap with residuals of 10-30 m/s^2 and the energy clamp acted on 7 of 180 steps.
        A descent direction in the constrained subspace (rhs . dx > 0), so the shared line search
        and stopping tests apply, with the same fixed point as solving the filtered system exactly.
        Measured on the default drop at dt = 1/30 s (docs/benchmarks/IMPLICIT.md): about as many outer
        iterations as solving the filtered system to cg_tol by PCG, at a third of the factor
        solves (1.8-2.9x faster), but the landing steps that reach the iteration cap end at larger
        residuals."""
        z, q, d = ti.static(self.pcg.z, self.pcg.q, self.objective.dx)
        self.precondition(self.objective.rhs, z)  # the factor's solve: the walk takes this step only while not Jacobi
        self.apply(z, q)
        for i in range(self.n):
            blk = self._jacobi_block(i)
            d[i] = z[i] + self.objective.filter(i, blk.inverse() @ (self.objective.rhs[i] - q[i]))
        self.pcg.rz[None] = 0.0
        for i in range(self.n):
            self.pcg.rz[None] += self.objective.rhs[i].dot(d[i])
        if self.pcg.rz[None] <= 0:  # not a descent direction: the factor solve alone is
            for i in range(self.n):
                d[i] = z[i]
        self.apply(d, q)
        self.pcg.rz[None] = 0.0
        self.pcg.pq[None] = 0.0
        for i in range(self.n):
            self.pcg.rz[None] += self.objective.rhs[i].dot(d[i])
            self.pcg.pq[None] += d[i].dot(q[i])
        alpha = ti.cast(0.0, float)
        if self.pcg.pq[None] > 0:
            alpha = self.pcg.rz[None] / self.pcg.pq[None]
        for i in range(self.n):
            d[i] *= alpha

    # -- L-BFGS (Liu, Bouaziz & Kavan 2017) ---------------------------------------------------------
    # The plain local/global iteration converges linearly, slowly where springs rotate or compress
    # a lot (the landing steps of a drop reached the 20-iteration cap with residuals of 10-100
    # m/s^2). L-BFGS with the global step as its initial inverse Hessian keeps the iteration's cost
    # (one global step, plus 4 * history dot products and updates over the particles) and learns
    # the curvature the constant matrix lacks from the last ``history`` updates of this step. The
    # pairs s = x_{k+1} - x_k, y = grad_{k+1} - grad_k (filtered: rhs_k - rhs_{k+1}) are kept only
    # while nothing is held and the objective stays the same: a held particle, a friction refreeze
    # or a new step drops them. (Pairs kept under contact, with four initial inverse Hessians, made
    # the drop's landing steps slower, not faster: docs/benchmarks/IMPLICIT.md, "Tried, not kept".) A
    # direction that is not a descent direction drops them too and takes the global step alone
    # (counted: lbfgs_restarts).
    @ti.func
    def _lbfgs_pair(self, x: ti.template()):
        """Complete the pair of the update accepted since the last direction, if it can be kept;
        save x and rhs for the next pair (nothing to do while particles are held)."""
        c = ti.static(self.sc)
        mh = ti.static(self.history)
        head = c.lb_head[None]
        held = ti.cast(c.n_active[None] > 0, ti.i32)
        # a pair needs an update since the last direction, with nothing held and the same objective
        keep = c.outer[None] > 0 and not held and not c.lb_held[None] and c.lb_updates[None] == c.updates[None]
        self.lb_dot[None] = 0.0
        for i in range(self.n):
            if keep:
                s = self.objective.u[i] - self.lb_x[i]
                y = self.lb_r[i] - self.objective.rhs[i]
                self.lb_s[i, head] = s
                self.lb_y[i, head] = y
                self.lb_dot[None] += s.dot(y)
            if not held:
                self.lb_x[i] = self.objective.u[i]
                self.lb_r[i] = self.objective.rhs[i]
        if not keep:
            c.lb_count[None] = 0
        elif self.lb_dot[None] > 0:
            self.lb_rho[head] = 1.0 / self.lb_dot[None]
            c.lb_head[None] = (head + 1) % mh
            c.lb_count[None] = ti.min(c.lb_count[None] + 1, mh)
        else:
            c.lb_count[None] = ti.min(c.lb_count[None], mh - 1)  # the slot just written held the oldest pair
        c.lb_updates[None] = c.updates[None]
        c.lb_held[None] = held
        c.lb_retry[None] = 0

    @ti.func
    def _lbfgs_first(self, j):
        """First loop of the two-loop recursion, pair j (0: newest), on rhs in place."""
        mh = ti.static(self.history)
        slot = (self.sc.lb_head[None] - 1 - j + mh) % mh
        self.lb_dot[None] = 0.0
        for i in range(self.n):
            self.lb_dot[None] += self.lb_s[i, slot].dot(self.objective.rhs[i])
        a = self.lb_rho[slot] * self.lb_dot[None]
        self.lb_alpha[slot] = a
        for i in range(self.n):
            self.objective.rhs[i] -= a * self.lb_y[i, slot]

    @ti.func
    def _lbfgs_second(self, j):
        """Second loop, pair j (0: oldest), on dx in place."""
        mh = ti.static(self.history)
        slot = (self.sc.lb_head[None] - self.sc.lb_count[None] + j + mh) % mh
        self.lb_dot[None] = 0.0
        for i in range(self.n):
            self.lb_dot[None] += self.lb_y[i, slot].dot(self.objective.dx[i])
        b = self.lb_alpha[slot] - self.lb_rho[slot] * self.lb_dot[None]
        for i in range(self.n):
            self.objective.dx[i] += b * self.lb_s[i, slot]

    @ti.func
    def _lbfgs_finish(self):
        """After a recursion over pairs: restore rhs; keep dx in the constrained subspace; no
        descent: drop the pairs and retry with the global step alone."""
        c = ti.static(self.sc)
        self.lb_dot[None] = 0.0
        for i in range(self.n):
            self.objective.rhs[i] = self.lb_r[i]
            self.objective.dx[i] = self.objective.filter(i, self.objective.dx[i])
            self.lb_dot[None] += self.objective.rhs[i].dot(self.objective.dx[i])
        if self.lb_dot[None] <= 0:
            c.lb_retry[None] = 1
            c.lb_count[None] = 0
            c.lb_restarts[None] += 1

    @ti.func
    def _set_cg_tol(self, tol):
        self.pcg.rel_tol[None] = self.cg_tol[None]  # the outer iteration corrects the rest

    def stats(self) -> dict:
        """Averages per step since the last call (or reset): local/global iterations, CG
        iterations, line-search halvings, friction refreezes, final residual [m/s^2]; the global
        solver and how often the matrix was factorised so far; restitution-limited and
        energy-clamped step counts."""
        a = self.accounts.take()
        steps = max(a["steps"], 1.0)
        return {
            "steps": int(a["steps"]),
            "local_global_iterations_per_step": a["outer"] / steps,
            "cg_iterations_per_step": a["cg"] / steps,
            "line_search_halvings_per_step": a["ls"] / steps,
            "final_residual_m_s2": a["res"] / steps,
            "global_solver": self.global_solver,
            "jacobi_pcg_now": bool(self.matrix.jacobi_now[None]),
            "factorizations": self.matrix.factorizations,
            "lbfgs_restarts_per_step": a["lb_restarts"] / steps,
            **contact_stats(a, steps, self.pairs),
        }
