"""What an implicit step did, counted: per-step accumulators (``acc``: scalars.STEP_ACCOUNTS) filled at each
step's end, and their read-out for ``stats()`` (``health.assess`` turns the counts of failed,
clamped and unconverged steps into warnings), and the work a step costs in spring passes.
"""

import taichi as ti

from .health import UNCONVERGED_FACTOR
from .scalars import read_accounts


@ti.data_oriented
class StepAccounts:
    """Mixin of ``ImplicitIntegrator``: the step's counters."""

    @ti.func
    def _account(self):
        self.acc.steps[None] += 1.0
        self.acc.outer[None] += ti.cast(self.sc.outer[None], ti.f64)
        self.acc.cg[None] += ti.cast(self.sc.cg[None], ti.f64)
        self.acc.ls[None] += ti.cast(self.sc.backtracks[None], ti.f64)
        self.acc.res[None] += ti.cast(self._residual(), ti.f64)
        self.acc.updates[None] += ti.cast(self.sc.updates[None], ti.f64)
        self.acc.clamped[None] += ti.cast(self.sc.clamped[None], ti.f64)
        self.acc.bounce[None] += ti.cast(self.sc.bounce_limited[None], ti.f64)
        self.acc.lb_restarts[None] += ti.cast(self.sc.lb_restarts[None], ti.f64)
        self.acc.bdf2[None] += ti.cast(self.scheme.bdf2_step[None], ti.f64)
        if self.sc.ls_failed[None]:
            self.acc.failed[None] += 1.0
            self.acc.failed_res[None] = ti.max(self.acc.failed_res[None], ti.cast(self._residual(), ti.f64))
        elif self.tol2[None] > 0 and self.sc.res2[None] > UNCONVERGED_FACTOR**2 * self.tol2[None]:
            self.acc.unconverged[None] += 1.0  # (a failed step is counted as failed only)

    @classmethod
    def spring_passes_per_step(cls, stats: dict) -> float:
        """One pass per objective evaluation (the reference, each iteration's gradient and each
        line-search trial: 1 + iterations + halvings) plus one per CG iteration (a Hessian
        product), from ``stats()``'s per-step averages."""
        outer = stats.get("newton_iterations_per_step", stats.get("local_global_iterations_per_step", 0.0))
        return 1.0 + outer + stats.get("line_search_halvings_per_step", 0.0) + stats.get("cg_iterations_per_step", 0.0)

    def _take_stats(self) -> dict:
        return read_accounts(self.acc)

    def _contact_stats(self, a: dict, steps: float) -> dict:
        """The counts of steps something intervened in or failed (``health.assess`` reads them)."""
        return {
            "failed_solve_steps": int(a["failed"]),
            "failed_solve_max_residual_m_s2": a["failed_res"],
            "friction_updates_per_step": a["updates"] / steps,
            "energy_clamped_steps": int(a["clamped"]),
            "restitution_limited_steps": int(a["bounce"]),
            "bdf2_steps": int(a["bdf2"]),
            "unconverged_steps": int(a["unconverged"]),
            **(self.pairs.stats(steps) if self.pairs is not None else {}),
        }
