"""Issue 24: an implicit step whose solve fails is counted and reported, never passed off as a result.

A solver whose direction is an ascent direction (the rhs reversed) cannot decrease the step's
objective: every iteration's line search fails. The driver must count each such step, and
``health.assess`` must turn the counts into a warning and call the run meaningless; the real
solvers on the same steps fail none.
"""
import taichi as ti

from physics_helpers import build, stretched
from taichi_soft.integrators import make_integrator
from taichi_soft.integrators.implicit.health import assess
from taichi_soft.integrators.implicit.newton import ImplicitEuler


@ti.data_oriented
class _Uphill(ImplicitEuler):
    """implicit_euler with its Newton direction replaced by an ascent direction."""

    @ti.func
    def _direction(self, x: ti.template()):
        for i in range(self.n):
            self.dx[i] = -self.rhs[i] * self.model.inv_mass[i]


def _stretched_cube():
    model, terrain = build(n=3, size=1.0, gravity=(0.0, -9.8, 0.0), stretch=(2000.0, 10.0),
                           shear=(2000.0, 10.0), bend=(2000.0, 10.0))
    state = model.state()
    state.set(stretched(model, (1.2, 0.9, 1.0)), model.v0_np)
    return model, terrain, state


def test_failed_line_searches_are_counted_and_make_the_run_meaningless():
    model, terrain, state = _stretched_cube()
    integ = _Uphill(model, terrain, None)
    assert integ.advance(state, 0.01, 5) == 5
    stats = integ.stats()
    assert stats["failed_solve_steps"] == 5
    assert stats["failed_solve_max_residual_m_s2"] > integ.options["newton_tol"]
    lines, meaningless = assess(stats)
    assert meaningless
    assert len(lines) == 1 and lines[0].startswith("5 of 5 steps ended with a failed line search")


def test_the_working_solver_fails_no_step():
    model, terrain, state = _stretched_cube()
    integ = make_integrator("implicit_euler", model, terrain)
    assert integ.advance(state, 0.01, 5) == 5
    stats = integ.stats()
    assert stats["failed_solve_steps"] == 0 and stats["energy_clamped_steps"] == 0
    assert assess(stats) == ([], False)


def test_a_clamp_on_many_steps_is_reported():
    lines, meaningless = assess({"steps": 10, "failed_solve_steps": 0, "failed_solve_max_residual_m_s2": 0.0,
                                 "energy_clamped_steps": 5})
    assert meaningless and lines == ["the energy clamp acted on 5 of 10 steps (they ended with more energy than "
                                     "they began with and their velocities were scaled down)"]
    assert assess({"steps": 100, "failed_solve_steps": 0, "failed_solve_max_residual_m_s2": 0.0,
                   "energy_clamped_steps": 1}) == ([], False)
