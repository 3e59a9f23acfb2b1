"""Options of the implicit integrators, typed and documented in one place (``..options``).

A scene sets them in its ``[solver]`` table or with ``--set solver.NAME=VALUE``; docs/implicit.md
lists them. ``ImplicitConfig`` holds the options of both solvers, ``ImplicitEulerConfig`` and
``FastMassSpringConfig`` each solver's own; the latter's ``resolve`` chooses the global solver.
"""

from dataclasses import dataclass
from typing import ClassVar

from ..base import SERIAL_MAX_PARTICLES, IntegratorConfig
from ..options import choice, flag, int_at_least, number_in, option
from .fast_mass_spring_laplacian import cholesky_pays


@dataclass(frozen=True)
class ImplicitConfig(IntegratorConfig):
    """Options of both solvers: the scheme, contact, line search, stopping, the last-resort energy clamp."""

    serial_max_particles: ClassVar[int] = SERIAL_MAX_PARTICLES  # many launches per step in parallel mode
    scheme: str = choice("backward_euler", ("bdf2", "sdirk2", "backward_euler"),
                         "time discretisation: bdf2 (second order) on steps whose history is smooth and that touch "
                         "no terrain, backward Euler elsewhere; sdirk2 (second order, L-stable, two solves a step) "
                         "on every step; backward_euler (first order) on every step")
    friction_velocity: float = option(1e-3, number_in(0.0, 1.0, lo_open=True), "a number in (0, 1]",
                                      "sliding speed [m/s] below which friction is smoothed (static-friction creep)")
    velocity_tol: float = option(1e-3, number_in(0.0, 1e3), "a number in [0, 1000]",
                                 "stop iterating once an update moves no particle faster than this [m/s] (0: off)")
    line_search_iters: int = option(12, int_at_least(0), "an integer >= 0",
                                    "most step halvings per iteration (backtracking on the step's objective)")
    friction_updates: int = option(10, int_at_least(0), "an integer >= 0",
                                   "most outer updates of the frozen friction multipliers per step")
    cg_iters: int = option(200, int_at_least(1), "an integer >= 1", "most CG iterations per linear solve")
    cg_tol: float = option(0.1, number_in(0.0, 1.0, lo_open=True), "a number in (0, 1]",
                           "relative CG residual of a linear solve")  # each solver's own default and meaning
    body_contact: bool = flag(True, "contact between bodies inside the step (multi-body scenes; false: bodies pass "
                                    "through each other, for comparisons)")
    contact_stiffness: float = option(1000.0, number_in(1.0, 1e8), "a number in [1, 1e8]",
                                      "body-body contact penalty kappa [-]: a pair's stiffness is kappa m_ij / h^2, "
                                      "so an approach stops at about 1 / (1 + kappa) of the overlap it would make")
    energy_clamp: bool = flag(True, "last resort: scale velocities back if a step still ends with more energy than it "
                                    "began with (every use is counted in stats())")

    # What each solver's own options say, for the shared driver:
    @property
    def residual_tol(self) -> float:
        """Residual [m/s^2] at which the iterations stop."""
        raise NotImplementedError

    @property
    def max_iterations(self) -> int:
        """Most iterations per step."""
        raise NotImplementedError

    @property
    def eisenstat_walker(self) -> bool:
        """Whether the CG tolerance follows the Eisenstat-Walker forcing term."""
        return False


@dataclass(frozen=True)
class ImplicitEulerConfig(ImplicitConfig):
    """``implicit_euler``'s options: Newton's iterations and its CG tolerance."""

    newton_iters: int = option(20, int_at_least(1), "an integer >= 1", "most Newton iterations per step")
    newton_tol: float = option(0.1, number_in(0.0, 1e3), "a number in [0, 1000]",
                               "residual [m/s^2] at which Newton stops (0: only the other tests stop it)")
    forcing: str = choice("eisenstat_walker", ("eisenstat_walker", "fixed"),
                          "CG tolerance per Newton iteration: min(0.5, sqrt(|r_k|/|r_0|)) (Eisenstat-Walker) "
                          "or the fixed cg_tol")
    cg_tol: float = option(1e-2, number_in(0.0, 1.0, lo_open=True), "a number in (0, 1]",
                           "relative (preconditioned) CG residual when forcing = fixed")

    residual_tol = property(lambda self: self.newton_tol)
    max_iterations = property(lambda self: self.newton_iters)
    eisenstat_walker = property(lambda self: self.forcing == "eisenstat_walker")


@dataclass(frozen=True)
class FastMassSpringConfig(ImplicitConfig):
    """``fast_mass_spring``'s options: iterations, the global solver, L-BFGS."""

    iterations: int = option(20, int_at_least(1), "an integer >= 1", "most local/global iterations per step")
    tol: float = option(0.1, number_in(0.0, 1e3), "a number in [0, 1000]",
                        "residual [m/s^2] at which iterations stop early (0: only the other tests stop them)")
    global_solver: str = choice("auto", ("auto", "cholesky", "pcg", "by_stiffness"),
                                "cholesky: prefactored skyline Cholesky (under contact see contact_solve); "
                                "pcg: matrix-free block-Jacobi PCG; by_stiffness: cholesky while "
                                "h^2 k_max / m_min <= 10 at the step, pcg on stiffer springs (faster impacts, worse "
                                "sliding); auto: cholesky on a CPU while the factor is small, else pcg")
    contact_solve: str = choice("auto", ("auto", "scaled", "pcg"),
                                "global step with particles held on the terrain while the factor is used: "
                                "scaled: one solve with the prefactored matrix and one block-Jacobi smoothing "
                                "step (friction), filtered, its length from the step's quadratic model; "
                                "pcg: the filtered system solved by PCG to cg_tol; auto: scaled while "
                                "h^2 k_max / m_min <= 10 at the step, pcg on stiffer springs")
    cg_tol: float = option(0.1, number_in(0.0, 1.0, lo_open=True), "a number in (0, 1]",
                           "relative CG residual of a global step (contact_solve = pcg, or global_solver = pcg)")
    history: int = option(5, lambda v: int_at_least(0)(v) and v <= 32, "an integer in [0, 32]",
                          "L-BFGS pairs kept within a step, the global step as the initial inverse Hessian "
                          "(Liu, Bouaziz & Kavan 2017); 0: plain local/global iterations")

    residual_tol = property(lambda self: self.tol)
    max_iterations = property(lambda self: self.iterations)

    def resolve(self, arch, fast_math, counts) -> "FastMassSpringConfig":
        """``global_solver = auto``: cholesky where it pays (``fast_mass_spring_laplacian.cholesky_pays``), else pcg."""
        out = super().resolve(arch, fast_math, counts)
        if out.global_solver == "auto":
            out = out.but(global_solver="cholesky" if cholesky_pays(arch, counts) else "pcg")
        return out
