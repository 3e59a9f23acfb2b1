"""What an implicit step did, counted: per-step accumulators (``acc``: scalars.STEP_ACCOUNTS) filled at each
step's end, and their read-out for ``stats()`` (``health.assess`` turns the counts of failed,
clamped and unconverged steps into warnings), and the work a step costs in spring passes.
"""

import taichi as ti

from .health import UNCONVERGED_FACTOR
from .scalars import RES_HISTORY, STEP_ACCOUNTS, accounts, read_accounts, zero_accounts


@ti.data_oriented
class StepAccounts:
    """The step's counters: a part of ``ImplicitIntegrator``.

    Given at construction: the step's scalars ``sc`` (scalars.py) and the ``scheme`` (scheme.py:
    whether the step was BDF2). Per step (``record``, at its end): the step's residual [m/s^2] and
    the tolerance on ``sc.res2`` it was solved to; per gradient (``residual_at``), its residual.
    Read out by ``take`` as sums since the last call, and by ``history`` as the last step's residuals.
    """

    def __init__(self, sc, scheme):
        self.sc, self.scheme = sc, scheme
        self.acc = accounts(STEP_ACCOUNTS)
        self.res_history = ti.field(float, RES_HISTORY)  # residual [m/s^2] per gradient of the last step
        self.n_history = ti.field(ti.i32, ())

    @ti.func
    def begin_step(self):
        """A new step: its residual history starts empty."""
        self.n_history[None] = 0

    @ti.func
    def residual_at(self, k, res):
        """The residual ``res`` [m/s^2] of the step's gradient k (0: at its start; the first
        ``RES_HISTORY`` are kept; a negative k, before any gradient, is not)."""
        if 0 <= k and k < RES_HISTORY:
            self.res_history[k] = res
            self.n_history[None] = ti.max(self.n_history[None], k + 1)

    def history(self) -> list[float]:
        """The residuals [m/s^2] recorded in the last step, in order."""
        return self.res_history.to_numpy()[: int(self.n_history[None])].tolist()

    @ti.func
    def record(self, residual, tol2):
        res = ti.cast(residual, ti.f64)
        stage = self.scheme.stage[None]
        # An SDIRK2 step's solves add up to one step (its first stage, a second stage taken again).
        if stage == 0 or stage == 3 or (stage == 2 and self.scheme.redo[None] == 0):
            self.acc.steps[None] += 1.0
        self.acc.outer[None] += ti.cast(self.sc.outer[None], ti.f64)
        self.acc.cg[None] += ti.cast(self.sc.cg[None], ti.f64)
        self.acc.ls[None] += ti.cast(self.sc.backtracks[None], ti.f64)
        self.acc.res[None] += res
        self.acc.updates[None] += ti.cast(self.sc.updates[None], ti.f64)
        self.acc.clamped[None] += ti.cast(self.sc.clamped[None], ti.f64)
        self.acc.bounce[None] += ti.cast(self.sc.bounce_limited[None], ti.f64)
        self.acc.lb_restarts[None] += ti.cast(self.sc.lb_restarts[None], ti.f64)
        self.acc.bdf2[None] += ti.cast(self.scheme.bdf2_step[None], ti.f64)
        if stage == 3:
            self.acc.sdirk2_fallback[None] += 1.0
        if self.sc.ls_failed[None]:
            self.acc.failed[None] += 1.0
            self.acc.failed_res[None] = ti.max(self.acc.failed_res[None], res)
        elif tol2 > 0 and self.sc.res2[None] > UNCONVERGED_FACTOR**2 * tol2:
            self.acc.unconverged[None] += 1.0  # (a failed step is counted as failed only)

    def take(self) -> dict:
        """The sums since the last call ({name: float}, scalars.STEP_ACCOUNTS), set back to 0."""
        return read_accounts(self.acc)

    def reset(self):
        zero_accounts(self.acc)
        self.n_history[None] = 0


def spring_passes_per_step(stats: dict) -> float:
    """One pass per objective evaluation (the reference, each iteration's gradient and each
    line-search trial: 1 + iterations + halvings) plus one per CG iteration (a Hessian
    product), from ``stats()``'s per-step averages."""
    outer = stats.get("newton_iterations_per_step", stats.get("local_global_iterations_per_step", 0.0))
    return 1.0 + outer + stats.get("line_search_halvings_per_step", 0.0) + stats.get("cg_iterations_per_step", 0.0)


def contact_stats(a: dict, steps: float, pairs) -> dict:
    """The counts of steps something intervened in or failed (``health.assess`` reads them), from
    the sums ``a`` over ``steps`` steps, and the body-body ``pairs``' counters (None: no pairs)."""
    return {
        "failed_solve_steps": int(a["failed"]),
        "failed_solve_max_residual_m_s2": a["failed_res"],
        "friction_updates_per_step": a["updates"] / steps,
        "energy_clamped_steps": int(a["clamped"]),
        "restitution_limited_steps": int(a["bounce"]),
        "bdf2_steps": int(a["bdf2"]),
        "sdirk2_fallback_steps": int(a["sdirk2_fallback"]),
        "unconverged_steps": int(a["unconverged"]),
        **(pairs.stats(steps) if pairs is not None else {}),
    }
