"""What an implicit step did, counted: per-step accumulators (``acc``, slots ``A_*``) filled at each
step's end, and their read-out for ``stats()`` (``health.assess`` turns the counts of failed,
clamped and unconverged steps into warnings), and the work a step costs in spring passes.
"""

import taichi as ti

from . import slots as S
from .health import UNCONVERGED_FACTOR


@ti.data_oriented
class StepAccounts:
    """Mixin of ``ImplicitIntegrator``: the step's counters."""

    @ti.func
    def _account(self):
        self.acc[S.A_STEPS] += 1.0
        self.acc[S.A_OUTER] += ti.cast(self.ctl[S.OUTER], ti.f64)
        self.acc[S.A_CG] += ti.cast(self.ctl[S.CG], ti.f64)
        self.acc[S.A_LS] += ti.cast(self.ctl[S.BACKTRACKS], ti.f64)
        self.acc[S.A_RES] += ti.cast(self._residual(), ti.f64)
        self.acc[S.A_UPDATES] += ti.cast(self.ctl[S.UPDATES], ti.f64)
        self.acc[S.A_CLAMPED] += ti.cast(self.ctl[S.CLAMPED], ti.f64)
        self.acc[S.A_BOUNCE] += ti.cast(self.ctl[S.BOUNCE_LIMITED], ti.f64)
        self.acc[S.A_LB_RESTARTS] += ti.cast(self.ctl[S.LB_RESTARTS], ti.f64)
        self.acc[S.A_BDF2] += ti.cast(self.bdf2_step[None], ti.f64)
        if self.ctl[S.LS_FAILED]:
            self.acc[S.A_FAILED] += 1.0
            self.acc[S.A_FAILED_RES] = ti.max(self.acc[S.A_FAILED_RES], ti.cast(self._residual(), ti.f64))
        elif self.tol2[None] > 0 and self.sc[S.RES2] > UNCONVERGED_FACTOR**2 * self.tol2[None]:
            self.acc[S.A_UNCONVERGED] += 1.0  # (a failed step is counted as failed only)

    @classmethod
    def spring_passes_per_step(cls, stats: dict) -> float:
        """One pass per objective evaluation (the reference, each iteration's gradient and each
        line-search trial: 1 + iterations + halvings) plus one per CG iteration (a Hessian
        product), from ``stats()``'s per-step averages."""
        outer = stats.get("newton_iterations_per_step", stats.get("local_global_iterations_per_step", 0.0))
        return 1.0 + outer + stats.get("line_search_halvings_per_step", 0.0) + stats.get("cg_iterations_per_step", 0.0)

    def _take_stats(self) -> list:
        a = [float(c) for c in self.acc.to_numpy()]
        self.acc.fill(0)
        return a

    def _contact_stats(self, a: list, steps: float) -> dict:
        """The counts of steps something intervened in or failed (``health.assess`` reads them)."""
        return {
            "failed_solve_steps": int(a[S.A_FAILED]),
            "failed_solve_max_residual_m_s2": a[S.A_FAILED_RES],
            "friction_updates_per_step": a[S.A_UPDATES] / steps,
            "energy_clamped_steps": int(a[S.A_CLAMPED]),
            "restitution_limited_steps": int(a[S.A_BOUNCE]),
            "bdf2_steps": int(a[S.A_BDF2]),
            "unconverged_steps": int(a[S.A_UNCONVERGED]),
            **(self.pairs.stats(steps) if self.pairs is not None else {}),
        }
