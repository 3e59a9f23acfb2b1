"""The parallel driver of the implicit step: Python sequences the same phases as the serial driver
(``driver._solve``, inside one kernel of many steps), one kernel launch per phase, so each phase's
loops over particles and springs run in parallel. Both call the same decision ti.funcs (``ctl``,
``sc``), so they take the same decisions (tests/test_implicit.py compares them).
"""

import taichi as ti

from . import slots as S


@ti.data_oriented
class ParallelDriver:
    """Mixin of ``ImplicitIntegrator``: the step's phases from Python scope."""

    def _advance_parallel(self, state, dt: float, n_steps: int) -> int:
        """``n_steps`` steps of ``dt`` [s], one launch per phase; returns the steps taken (to divergence)."""
        start = self._step_counter
        for k in range(n_steps):
            self._k_begin(state.x, state.v, dt)
            he = float(self.h_eff[None])
            self._solve_python(state.x, he)
            self._end_python(state.x, state.v, he, start + k)
            if self.diverged:
                break
        self._step_counter += n_steps
        bad = int(self.diverged_step[None])
        return bad - start + 1 if self.diverged else n_steps

    def _solve_python(self, x, dt):
        for _ in range(int(self.max_iters[None]) + int(self.max_updates[None]) + 3):
            searching = self.ctl[S.PHASE] < 2
            if not searching:
                self._k_gradient_decide(x, dt)
                if self.ctl[S.DONE]:
                    break
                searching = not self.ctl[S.UPDATE]
                if searching:
                    self._direction_python(x)
                    self._k_after_direction()
                    if self.pairs is not None:
                        self._k_pairs_check()
                        if self.pairs.again[None]:
                            self._k_pairs_regather()
            if searching:
                for _ in range(int(self.ctl[S.LS_LIMIT]) + 1):
                    self._k_trial_decide(x, dt)
                    if self.ctl[S.LS_DONE]:
                        break
                self._k_accept(x)
                if self.ctl[S.DONE]:
                    break

    @ti.kernel
    def _k_begin(self, x: ti.template(), v: ti.template(), dt: float):
        self._begin_step(x, v, dt)

    @ti.kernel
    def _k_trial_decide(self, x: ti.template(), dt: float):
        self._trial(x, dt)
        self._line_search_decide()

    @ti.kernel
    def _k_accept(self, x: ti.template()):
        self._accept(x)

    @ti.kernel
    def _k_gradient_decide(self, x: ti.template(), dt: float):
        self._gradient(x, dt)
        self._after_gradient(dt)

    @ti.kernel
    def _k_add_cg(self, iters: ti.i32):
        self.ctl[S.CG] += iters

    @ti.kernel
    def _k_after_direction(self):
        self._after_direction()

    @ti.kernel
    def _k_pairs_check(self):
        self.pairs.check()

    @ti.kernel
    def _k_pairs_regather(self):
        self.pairs.regather()

    def _end_python(self, x, v, dt, step):
        self._k_end_velocities(x, dt)
        if self.terrain.has_contact:
            self._bounce_spread_python()
        self._k_end_finish(x, v, step)

    @ti.kernel
    def _k_end_velocities(self, x: ti.template(), dt: float):
        self._end_velocities(x, dt)

    @ti.kernel
    def _k_end_finish(self, x: ti.template(), v: ti.template(), step: ti.i32):
        self._end_finish(x, v, step)

