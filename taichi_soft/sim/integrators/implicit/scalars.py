"""The implicit step's scalars, by name: one Taichi struct field each for the step and for its counts.

``step_scalars()`` (``ImplicitIntegrator.sc``): what every phase of a step reads and writes, the
objective values, residuals and line-search state (f64 in either precision: their sums run over
all particles) and the driver's decisions and counters (i32). Decisions are taken in ti.funcs that
write these members, so the serial (in-kernel) and parallel (Python-driven) drivers take the same
decisions. Read and written as ``sc.<name>[None]`` in kernels and from Python scope alike (a
member is a 0-D field: from Python, one read per member, not the whole struct).

``accounts(STEP_ACCOUNTS)`` (``StepAccounts.acc``): f64 sums over the steps since the last
``stats()`` call (accounts.py); ``accounts(PAIR_ACCOUNTS)``: the body-body pair terms' (pairs.py).
"""

import numpy as np
import taichi as ti

# name: meaning [unit]. f64.
STEP_REALS = {
    "res2": "squared residual sum_i |r_i|^2 / m_i of the last gradient [kg m^2]",
    "res2_0": "res2 at the step's first gradient [kg m^2]",
    "res_prev": "residual of the last gradient (release margin of the active set) [m/s^2]",
    "f_cur": "objective at the current iterate [kg m^2]",
    "f_trial": "objective at the line-search trial point [kg m^2]",
    "dec": "grad . (x_trial - x): first-order decrease predicted for the trial [kg m^2]",
    "n_active": "particles held on the terrain, plus body-body pairs in contact, plus a grabbed particle "
                "(grab.py), after the last gradient",
    "alpha": "line-search step fraction of the trial",
    "step": "largest particle move of the last accepted update [m]",
    "step_trial": "largest particle move of the trial [m]",
    "e_trial": "spring energy at the trial point [J]",
    "e_cur": "spring energy at the current iterate [J]",
    "h_start": "total energy (kinetic + springs; gravity is measured from x_n) at the start of the step [J]",
    "g_stage": "SDIRK2's second stage: sum m g . (X1 - x_n), gravity's energy at x_n measured from X1 [J]",
    "h_scale": "kinetic + springs at the start: with the end's energies, the scale of the balance's round-off [J]",
    "k_start": "kinetic energy at the start [J]",
    "lam_change": "sum |lam_candidate - lam_frozen| over held particles [kg m]",
    "lam_sum": "sum lam_candidate over held particles [kg m]",
    "t_max": "largest feasible fraction of the predicted step",
    "bounce_a": "restitution: sum 1/2 m |dv|^2 [J]",
    "bounce_b": "restitution: sum m v . dv [J]",
    "k_solve": "kinetic energy of the solved velocities [J]",
    "g_end": "gravity energy at the end, from x_n: -sum m g . (x - x_n) [J]",
    "k_end": "kinetic energy after the collision response [J]",
    "h2_prev": "h^2 of the previous step (the multipliers kept for the warm start are in its units) [s^2]",
    "n_pairs": "body-body pairs in contact after the last gradient (pairs.py; also counted in n_active)",
    "n_bounce": "held particles given a restitution velocity in this step's end",
    "dt_step": "h of this step (the scheme's h_eff may be 2 h / 3) [s]",
}

# name: meaning. i32; every one is zeroed at each step's start (``counters``).
STEP_INTS = {
    "done": "1: the step's iteration is over",
    "update": "1: the next gradient refreezes the friction multipliers",
    "updates": "outer friction updates taken in this step",
    "accepted": "the line search accepted its trial",
    "ls_done": "the line search is over",
    "ls_count": "halvings in this line search",
    "ls_limit": "most halvings in this line search",
    "outer": "Newton / local-global iterations taken in this step",
    "cg": "CG iterations in this step",
    "backtracks": "line-search halvings in this step",
    "evals": "gradient evaluations in this step",
    "phase": "0: reference at x_n, 1: feasible start, 2: iterating",
    "clamped": "1: the energy clamp acted on this step",
    "bounce_limited": "1: restitution was scaled down to the energy the step lost",
    # fast_mass_spring's L-BFGS history (fast_mass_spring.py)
    "lb_count": "pairs (s, y) kept",
    "lb_head": "slot the next pair goes to",
    "lb_updates": "friction refreezes (updates) when the last direction was taken",
    "lb_held": "1: particles were held when the last direction was taken",
    "lb_retry": "1: the L-BFGS direction was no descent direction; take the global step alone",
    "lb_restarts": "such restarts in this step",
    "ls_failed": "1: an iteration's line search failed before the step converged (the step ended there)",
}

# name: meaning. f64 sums over steps (accounts.py turns them into ``stats()``).
STEP_ACCOUNTS = {
    "steps": "steps taken",
    "outer": "Newton / local-global iterations",
    "cg": "CG iterations",
    "ls": "line-search halvings",
    "res": "final residuals [m/s^2]",
    "updates": "friction refreezes",
    "clamped": "steps the energy clamp acted on",
    "bounce": "steps whose restitution was limited to the energy lost",
    "lb_restarts": "L-BFGS restarts",
    "failed": "steps whose line search failed unconverged",
    "failed_res": "the largest residual such a step ended with (a maximum, not a sum) [m/s^2]",
    "bdf2": "BDF2 steps",
    "sdirk2_fallback": "SDIRK2 steps whose second stage gained energy and was taken again as backward Euler",
    "unconverged": "steps that ended above UNCONVERGED_FACTOR times the tolerance",
}

# name: meaning. f64 sums over steps of the body-body pair terms (pairs.py, pair_list.py).
PAIR_ACCOUNTS = {
    "contact": "pairs in contact at a step's end",
    "removed": "overlap (w o) the predictor would have made, less what is left at the end [m]",
    "deepest": "deepest particle in another body at the end of any step (a maximum; pairs.py) [m]",
    "overflow": "candidate pairs a full list could not keep",
    "trust": "trials outside the tube",
    "pairs": "candidate pairs",
    "bounces": "restitution bounces",
    "gathers": "pair lists rebuilt for a search direction",
    "most": "the most candidate pairs in one list (a maximum)",
    "refrozen": "penalty energy at a step's start with its geometry, less the last step's end [J]",
}

START_HALVINGS = 3  # most halvings of the feasible start fraction before starting at x_n
RES_HISTORY = 64  # residuals of the last step's gradient evaluations kept for inspection


def step_scalars():
    """The step's scalars: ``STEP_REALS`` (f64) and ``STEP_INTS`` (i32) as one struct field."""
    return ti.Struct.field({**{k: ti.f64 for k in STEP_REALS}, **{k: ti.i32 for k in STEP_INTS}}, shape=())


def counters(sc) -> list:
    """The i32 members of ``step_scalars()`` (zeroed at each step's start)."""
    return [getattr(sc, k) for k in STEP_INTS]


def accounts(names: dict):
    """An f64 struct field with a member per name of ``names`` (``STEP_ACCOUNTS``, ``PAIR_ACCOUNTS``)."""
    return ti.Struct.field({k: ti.f64 for k in names}, shape=())


# Read and zeroed by one kernel: Taichi's ``to_numpy`` and ``fill`` of a struct field compile a
# kernel per member (docs/decisions/batched-scalar-writes.md).
def read_accounts(acc) -> dict:
    """The members of an ``accounts`` field as floats by name, then zeroed."""
    values = np.zeros(len(acc.keys), dtype=np.float64)
    _take_members(acc, values)
    return {k: float(v) for k, v in zip(acc.keys, values)}


def zero_accounts(acc):
    """Set every member of an ``accounts`` field to 0 (the read-out's kernel, its values dropped)."""
    _take_members(acc, np.zeros(len(acc.keys), dtype=np.float64))


@ti.kernel
def _take_members(acc: ti.template(), out: ti.types.ndarray(dtype=ti.f64, ndim=1)):
    for j in ti.static(range(len(acc.keys))):
        out[j] = acc.field_dict[acc.keys[j]][None]
        acc.field_dict[acc.keys[j]][None] = 0.0
