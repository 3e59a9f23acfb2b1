"""``fast_mass_spring``'s search direction as walks (walk.py): the global step, and L-BFGS over it.

Its phases beyond the shared ones (the factor's solve, the scaled contact step, the L-BFGS
two-loop recursion: ti.funcs of fast_mass_spring.py) are declared in ``PHASES``, one line each;
both executors are generated from it.
"""

import taichi as ti

from .walk import COUNT, FIELD, Walk


def _global_step(integ, ph, x):
    """dx from rhs by the global step alone (the plain local/global iteration's direction)."""
    if ti.static(integ.factorised):
        if integ.matrix.jacobi_now[None]:
            ph.cg(integ.objective.rhs, integ.objective.dx)  # stiff springs (by_stiffness): Jacobi PCG, as pcg
        elif integ.sc.n_active[None] == 0:
            ph.factor_solve(integ.objective.rhs, integ.objective.dx)  # nothing held: the factorisation is exact
        elif ti.static(integ.scaled_contact) and integ.sc.n_pairs[None] == 0 and integ.matrix.scaled_now[None]:
            # (pairs in contact: PCG, below; the scaled step's one smoothing sweep cannot carry the
            # stiff pair penalty, and local/global then stalled at the velocity test)
            ph.scaled_direction()
        else:
            ph.cg(integ.objective.rhs, integ.objective.dx)
    else:
        ph.cg(integ.objective.rhs, integ.objective.dx)


GLOBAL_STEP = Walk(_global_step)


def _lbfgs_direction(integ, ph, x):
    """The global step as the initial inverse Hessian of L-BFGS over this step's pairs (none with
    ``history = 0``); a direction that is no descent direction is retried with the global step
    alone (fast_mass_spring.py, ``_lbfgs_finish``)."""
    if ti.static(integ.history):
        ph.lbfgs_pair(x)
        for attempt in range(2):
            if attempt == 0 or integ.sc.lb_retry[None]:
                count = integ.sc.lb_count[None]  # 0: the global step alone
                for j in range(count):
                    ph.lbfgs_first(j)
                ph.walk(GLOBAL_STEP, x)
                for j in range(count):
                    ph.lbfgs_second(j)
                if count > 0:
                    ph.lbfgs_finish()
    else:
        ph.walk(GLOBAL_STEP, x)


LBFGS_DIRECTION = Walk(_lbfgs_direction)


# fast_mass_spring's own phases, added to the shared ones (walk.py): name -> (its ti.func in
# fast_mass_spring.py; the kinds of its arguments).
PHASES = {
    "factor_solve": ("_factor_solve", (FIELD, FIELD)),  # b, out
    "scaled_direction": ("_scaled_direction", ()),
    "lbfgs_pair": ("_lbfgs_pair", (FIELD,)),  # x
    "lbfgs_first": ("_lbfgs_first", (COUNT,)),  # the pair j
    "lbfgs_second": ("_lbfgs_second", (COUNT,)),  # the pair j
    "lbfgs_finish": ("_lbfgs_finish", ()),
}
