"""What the implicit step needs from a solver's linear operator, named in one place.

An implicit solver (implicit_euler.py, fast_mass_spring.py) is its own linear operator: the class
implements the ti.funcs of ``LinearOperator`` under these public names. Two parts use them:

* the objective's gradient pass (objective.py) hands the operator what it computes on the way --
  each spring's 3x3 Hessian block and, per particle once its friction, pair and grab blocks are
  known, the cue to store that particle's preconditioner -- and asks whether the operator's matrix
  already carries the grab;
* the linear solves (``linalg.PCG``, the restitution spread of restitution.py, the solver's own
  direction) apply the operator and its preconditioner.

The protocol is a contract on names and call shapes, not a base class: the methods are ti.funcs
inlined into the step's kernels, so the calls compile to exactly what the solver's methods are.
``require`` checks an operator at construction, so a solver missing one fails there, loudly,
instead of at a kernel's compile.
"""

import taichi as ti


class LinearOperator:
    """The linear operator H of a step's search direction (H dx = rhs), as the step's parts call it.

    All are ti.funcs, called inside the step's kernels; ``src``, ``dst`` are per-particle vec3
    fields (templates). Units: a block or H's rows [kg] (H times a displacement [m] is a gradient
    [kg m]); a preconditioner's blocks [1/kg].
    """

    METHODS = ("store_spring_hessian", "store_preconditioner", "grab_factored",
               "apply", "prepare_preconditioner", "precondition")

    @ti.func
    def store_spring_hessian(self, s, block):
        """Keep spring ``s``'s 3x3 block h^2 E_s'' + h kd l l^T [kg] of this gradient (an operator
        with a constant matrix ignores it). Called once per spring, before any ``store_preconditioner``."""

    @ti.func
    def store_preconditioner(self, i):
        """Particle ``i``'s blocks are complete (springs, and ``Objective.fric_hess[i]``: friction,
        pairs, grab): store what ``precondition`` needs for it, or nothing."""

    @ti.func
    def grab_factored(self, i):
        """Whether the operator's matrix already carries the grab on particle ``i``; if not, a
        grabbed particle counts as held (objective.py). Returns a boolean."""

    @ti.func
    def apply(self, src: ti.template(), dst: ti.template()):
        """dst = H src, H symmetric positive semi-definite, filtered as the objective filters its rows."""

    @ti.func
    def prepare_preconditioner(self):
        """Called once at the start of each solve, before the first ``precondition``."""

    @ti.func
    def precondition(self, src: ti.template(), dst: ti.template()):
        """dst = P^-1 src, P^-1 symmetric positive semi-definite."""


def require(operator):
    """``operator`` itself if it has every ``LinearOperator`` method as a ti.func; else a TypeError
    naming what is missing."""
    missing = [name for name in LinearOperator.METHODS
               if not getattr(getattr(operator, name, None), "_is_taichi_function", False)]
    if missing:
        raise TypeError(f"{type(operator).__name__} is not a linear operator of the implicit step: "
                        f"no ti.func {', '.join(missing)} (implicit/operator.py)")
    return operator
