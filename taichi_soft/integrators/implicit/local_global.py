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
factorisation (``"pcg"``). The global step is a descent direction of g
(M + L is SPD), so the shared driver's line search keeps g(x_k) <= g(x_n) at every iterate, and
its stopping tests apply as for Newton.
"""

import taichi as ti

from ...linalg import PCG, SkylineCholesky
from ..base import register
from . import options as opt
from . import slots as S
from .driver import ImplicitIntegrator

CHOLESKY_AUTO_MAX = 10_000_000  # largest factor envelope [values] global_solver = "auto" factorises


@register
@ti.data_oriented
class FastMassSpring(ImplicitIntegrator):
    """Local/global solver of Liu et al. 2013 on the same objective, prefactorised global matrix."""

    name = "fast_mass_spring"
    description = "fast mass-spring (Liu et al. 2013): local/global iterations, prefactored constant matrix"
    OPTIONS = {**ImplicitIntegrator.OPTIONS, **opt.spec(opt.LOCAL_GLOBAL)}

    def __init__(self, model, terrain, options=None):
        n = model.n_particles
        chosen = self.parse_options(options or {})
        solver = chosen["global_solver"]
        if solver == "auto":
            # The triangular solves are serial: the Cholesky wins on a CPU, PCG on a GPU. Its
            # envelope grows like N^(5/3) for a cube (N particles), factorising like N^(7/3): past
            # CHOLESKY_AUTO_MAX values (the 20^3 cube has 6.4e6; the 40^3 one 2e8, 1.6 GB in f64
            # and an hour-long factorisation) auto takes PCG.
            cpu = ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64)
            small = SkylineCholesky.envelope_size(n, model.pairs_np) <= CHOLESKY_AUTO_MAX
            solver = "cholesky" if cpu and small else "pcg"
        self.global_solver = solver
        # Fixed at construction (an option), so a compile-time constant.
        self.scaled_contact = solver == "cholesky" and chosen["contact_solve"] == "scaled"
        self.group_c = ti.field(float, model.n_groups)  # Laplacian weight h^2 k + h kd [kg]
        self.diag = ti.field(float, n)  # diagonal of M + L (PCG's Jacobi preconditioner) [kg]
        if solver == "cholesky":
            self.chol = SkylineCholesky(n, model.pairs_np)
        self.pcg = PCG(n)
        self._matrix_key = None
        self.factorizations = 0
        super().__init__(model, terrain, options)

    def _tol(self):
        return self.options["tol"]

    def _max_iterations(self):
        return self.options["iterations"]

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
    # normal component of dx fixed to 0 for held particles (as in the Newton solve). With nothing
    # held the plain triangular solve is exact. With held particles, "pcg" solves the filtered
    # system by PCG preconditioned by the prefactored Cholesky of the unconstrained A (a few
    # iterations: the constraints perturb A by a low-rank change), "scaled" takes only its first
    # direction (see _scaled_direction).
    @ti.func
    def _store_spring_hessian(self, s, hs):
        pass  # A is constant; the friction blocks come from the gradient

    @ti.func
    def _store_preconditioner(self, i):
        pass

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
            q = self.diag[i] * src[i] + self.fric_hess[i] @ src[i]  # friction: not in the factorisation
            for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                q -= self.group_c[m.adj_group[e]] * src[m.adj_other[e]]
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
        Measured on the default drop at dt = 1/30 s (docs/implicit.md): about as many outer
        iterations as solving the filtered system to cg_tol by PCG, at a third of the factor
        solves (1.8-2.9x faster), but the landing steps that reach the iteration cap end at larger
        residuals."""
        z, q, d = ti.static(self.pcg.z, self.pcg.q, self.dx)
        self.precondition(self.rhs, z)
        self.apply(z, q)
        for i in range(self.n):
            blk = self.diag[i] * ti.Matrix.identity(float, 3) + self.fric_hess[i]
            d[i] = z[i] + self._filter(i, blk.inverse() @ (self.rhs[i] - q[i]))
        self.pcg.rz[None] = 0.0
        for i in range(self.n):
            self.pcg.rz[None] += self.rhs[i].dot(d[i])
        if self.pcg.rz[None] <= 0:  # not a descent direction: the factor solve alone is
            for i in range(self.n):
                d[i] = z[i]
        self.apply(d, q)
        self.pcg.rz[None] = 0.0
        self.pcg.pq[None] = 0.0
        for i in range(self.n):
            self.pcg.rz[None] += self.rhs[i].dot(d[i])
            self.pcg.pq[None] += d[i].dot(q[i])
        alpha = ti.cast(0.0, float)
        if self.pcg.pq[None] > 0:
            alpha = self.pcg.rz[None] / self.pcg.pq[None]
        for i in range(self.n):
            d[i] *= alpha

    @ti.func
    def _direction(self):
        if ti.static(self.global_solver == "cholesky"):
            if self.sc[S.N_ACTIVE] == 0:
                self.chol.solve(self.rhs, self.dx)  # nothing held: the factorisation is exact
            elif ti.static(self.scaled_contact):
                self._scaled_direction()
            else:
                self.pcg.solve(self, self.rhs, self.dx, self.cg_iters[None])
                self.ctl[S.CG] += self.pcg.iters[None]
        else:
            self.pcg.solve(self, self.rhs, self.dx, self.cg_iters[None])
            self.ctl[S.CG] += self.pcg.iters[None]

    @ti.kernel
    def _k_scaled_direction(self):
        self._scaled_direction()

    def _direction_python(self):
        if self.global_solver == "cholesky" and self.sc[S.N_ACTIVE] == 0:
            self.chol.solve_kernel(self.rhs, self.dx)
        elif self.scaled_contact:
            self._k_scaled_direction()
        else:
            self._k_add_cg(self.pcg.solve_parallel(self, self.rhs, self.dx, int(self.cg_iters[None])))

    @ti.func
    def _set_cg_tol(self, tol):
        self.pcg.rel_tol[None] = self.cg_tol[None]  # the outer iteration corrects the rest

    def stats(self) -> dict:
        """Averages per step since the last call (or reset): local/global iterations, CG
        iterations, line-search halvings, friction refreezes, final residual [m/s^2]; the global
        solver and how often the matrix was factorised so far; restitution-limited and
        energy-clamped step counts."""
        a = self._take_stats()
        steps = max(a[S.A_STEPS], 1.0)
        return {
            "steps": int(a[S.A_STEPS]),
            "local_global_iterations_per_step": a[S.A_OUTER] / steps,
            "cg_iterations_per_step": a[S.A_CG] / steps,
            "line_search_halvings_per_step": a[S.A_LS] / steps,
            "final_residual_m_s2": a[S.A_RES] / steps,
            "global_solver": self.global_solver,
            "factorizations": self.factorizations,
            **self._contact_stats(a, steps),
        }
