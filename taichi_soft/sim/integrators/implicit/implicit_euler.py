"""``implicit_euler``: backward Euler by Newton's method on the step's objective.

The Hessian is applied matrix-free (Baraff & Witkin 1998), each spring's 3x3 block
h^2 k (l l^T + max(0, 1 - r/|d|)(I - l l^T)) + h kd l_s l_s^T stored once per spring (the clamp
of the transverse factor under compression keeps it PSD, Choi & Ko 2002, so every direction is a
descent direction); PCG with the 3x3 block-Jacobi preconditioner, an Eisenstat-Walker forcing
term by default. Line search, contact and stopping are the shared driver's (driver.py).
"""

import taichi as ti

from ...allocation import allocate
from ...footprint import MAT, FieldCounts, per_particle, per_spring
from ...model import code_spring
from ..base import MB, register
from .accounts import contact_stats
from .driver import ImplicitIntegrator
from .options import ImplicitEulerConfig


@ti.data_oriented
class SpringHessian:
    """``implicit_euler``'s linear operator data: a part of it.

    Input, given at construction: the ``model`` (masses, the adjacency); per call, the blocks the
    gradient pass computes. Outputs: the Hessian's product with a vector and its block-Jacobi
    preconditioner, both per particle, for the solver's PCG operator.
    """

    BUFFERS = {
        "spring_hess": per_spring("h^2 (PSD spring Hessian) + h kd l l^T [kg]", MAT),
        "precond": per_particle("inverse 3x3 diagonal blocks, the block-Jacobi preconditioner [1/kg]", MAT),
    }

    def __init__(self, model):
        """Allocates the fields only (no write: the owner's pending SNode tree stays open)."""
        self.model = model
        self.n = model.n_particles
        allocate(self, self.BUFFERS, self.n, model.n_springs)

    @ti.func
    def store_spring(self, s, hs):
        self.spring_hess[s] = hs

    @ti.func
    def diagonal(self, i, extra):
        """Particle i's 3x3 diagonal block [kg]: its mass, its springs' blocks and ``extra`` (friction,
        pairs, grab)."""
        m = self.model
        diag = m.mass[i] * ti.Matrix.identity(float, 3) + extra
        for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
            diag += self.spring_hess[code_spring(m.adj_spring[e])]
        return diag

    @ti.func
    def product(self, i, src: ti.template(), extra):
        """Row i of H src, H = M + h^2 K_psd + h D + ``extra`` (particle i's block outside the
        springs), gathering its springs' blocks (no atomics, no assembled matrix)."""
        m = self.model
        q = m.mass[i] * src[i] + extra @ src[i]
        for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
            s = m.adj_spring[e]
            q += self.spring_hess[code_spring(s)] @ (src[i] - src[m.adj_other[e]])
        return q

    @ti.func
    def precondition(self, src: ti.template(), dst: ti.template()):
        for i in range(self.n):
            dst[i] = self.precond[i] @ src[i]


@register
@ti.data_oriented
class ImplicitEuler(ImplicitIntegrator):
    """Backward Euler by Newton's method on g(x), matrix-free PCG, Armijo backtracking."""

    name = "implicit_euler"
    description = "backward Euler: Newton + block-Jacobi PCG on the step's energy, line search (stable at frame-sized steps)"
    Config = ImplicitEulerConfig
    FIELDS = ImplicitIntegrator.FIELDS + FieldCounts.of(SpringHessian.BUFFERS)  # and its Hessian's
    BASE_BYTES = 175 * MB  # measured (memory.py): process, runtime, compiled kernels

    def __init__(self, model, terrain, options=None, contacts=None):
        self.hessian = SpringHessian(model)  # the Newton system's blocks
        super().__init__(model, terrain, options, contacts)

    # -- its linear operator (operator.LinearOperator): the filtered Hessian
    # H = M + h^2 K_psd + h D + friction, pairs and grab, applied per particle
    @ti.func
    def store_spring_hessian(self, s, hs):
        self.hessian.store_spring(s, hs)

    @ti.func
    def store_preconditioner(self, i):
        """Inverse of particle i's diagonal block (mass, springs, friction), filtered if held."""
        block = self.hessian.diagonal(i, self.objective.fric_hess[i])
        self.hessian.precond[i] = self.objective.filtered_inverse(i, block)

    @ti.func
    def apply(self, src: ti.template(), dst: ti.template()):
        for i in range(self.n):
            dst[i] = self.objective.filter(i, self.hessian.product(i, src, self.objective.fric_hess[i]))
        if ti.static(self._has_pairs()):
            self.pairs.apply(src, dst)

    @ti.func
    def prepare_preconditioner(self):
        pass  # stored with the gradient (store_preconditioner)

    @ti.func
    def precondition(self, src: ti.template(), dst: ti.template()):
        self.hessian.precondition(src, dst)

    def stats(self) -> dict:
        """Averages per step since the last call (or reset): Newton and CG iterations, line-search
        halvings, friction refreezes, the final residual [m/s^2] (see ``Objective.residual``);
        counts of steps whose restitution was limited to the energy the step lost, and of
        energy-clamped steps."""
        a = self.accounts.take()
        steps = max(a["steps"], 1.0)
        return {
            "steps": int(a["steps"]),
            "newton_iterations_per_step": a["outer"] / steps,
            "cg_iterations_per_step": a["cg"] / steps,
            "cg_iterations_per_newton": a["cg"] / max(a["outer"], 1.0),
            "line_search_halvings_per_step": a["ls"] / steps,
            "final_residual_m_s2": a["res"] / steps,
            **contact_stats(a, steps, self.pairs),
        }
