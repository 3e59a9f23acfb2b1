"""An implicit step whose solve fails is counted and reported, never passed off as a result.

A solver whose direction is an ascent direction (the rhs reversed) cannot decrease the step's
objective: every iteration's line search fails. The driver must count each such step, and
``health.assess`` must turn the counts into a warning and call the run meaningless (the real
solvers fail no step: tests/test_f32_implicit.py).
"""
import taichi as ti

from taichi_soft.sim.integrators.implicit.health import assess
from taichi_soft.sim.integrators.implicit.implicit_euler import ImplicitEuler
from taichi_soft.sim.integrators.implicit.walk import Walk


def _ascent_direction(integ, ph, x):
    ph.ascent()


@ti.data_oriented
class _Uphill(ImplicitEuler):
    """implicit_euler with its Newton direction replaced by an ascent direction (a direction walk
    of its own, with its phase declared in ``PHASES``: both executors run it, walk.py)."""

    DIRECTION = Walk(_ascent_direction)
    PHASES = {**ImplicitEuler.PHASES, "ascent": ("_ascent", ())}

    @ti.func
    def _ascent(self):
        for i in range(self.n):
            self.objective.dx[i] = -self.objective.rhs[i] * self.model.inv_mass[i]


def test_failed_line_searches_are_said_and_the_run_exits_non_zero(monkeypatch, capsys, tmp_path):
    """Through `run`: every step fails, so stderr says so, the summary counts it and calls the
    result meaningless, and the exit status is EXIT_UNRELIABLE (6), not 0."""
    import json

    from taichi_soft import cli
    from taichi_soft.commands import common
    from taichi_soft.sim.integrators import REGISTRY

    monkeypatch.setitem(REGISTRY, "uphill", _Uphill)
    monkeypatch.setattr(_Uphill, "name", "uphill")
    monkeypatch.setattr(common, "start_taichi", lambda args: None)  # conftest's runtime is running
    summary = tmp_path / "s.json"
    code = cli.main(["run", "--set", "body.0.n=3", "--set", "body.0.initial_stretch=[1.2, 0.9, 1.0]",
                     "--integrator", "uphill", "--dt", "0.01", "--duration", "0.05", "--summary", str(summary)])
    err = capsys.readouterr().err
    assert code == cli.EXIT_UNRELIABLE == 6, err
    assert "warning: plane/uphill: 5 of 5 steps ended with a failed line search" in err
    assert "result is meaningless" in err
    s = json.loads(summary.read_text())
    assert s["meaningless"] is True and len(s["solver_warnings"]) == 1
    assert s["integrator_stats"]["failed_solve_steps"] == 5
    assert s["integrator_stats"]["failed_solve_max_residual_m_s2"] > ImplicitEuler.Config.newton_tol
    lines, meaningless = assess(s["integrator_stats"])
    assert meaningless and lines == s["solver_warnings"]


def test_a_clamp_on_many_steps_is_reported():
    lines, meaningless = assess({"steps": 10, "failed_solve_steps": 0, "failed_solve_max_residual_m_s2": 0.0,
                                 "energy_clamped_steps": 5})
    assert meaningless and lines == ["the energy clamp acted on 5 of 10 steps (they ended with more energy than "
                                     "they began with and their velocities were scaled down)"]
    assert assess({"steps": 100, "failed_solve_steps": 0, "failed_solve_max_residual_m_s2": 0.0,
                   "energy_clamped_steps": 1}) == ([], False)


def test_unconverged_steps_are_counted_and_said_when_they_are_most():
    """A stiff cube (x100) pushed across the plane at 3 m/s, 1/30 s: fast_mass_spring's local/global
    iterations with the scaled contact step stop at their cap far from the solution on every step
    (and the cube stops; ``contact_solve = auto`` takes PCG there, test_implicit.py), and
    the counter says so; Newton with a cap that lets it converge counts none, and the cube loses
    exactly Coulomb's mu g h per step. ``assess`` speaks when unconverged steps are most."""
    from taichi_soft.bench import precision as P
    from taichi_soft.bench.plausibility import PUSH_SPEED, push_run
    from taichi_soft.sim.integrators.implicit.health import UNCONVERGED_WARN_SHARE

    scene, sets, _ = push_run(True)
    h, steps = 1 / 30, 6
    for name, options, unconverged in (("fast_mass_spring", {"contact_solve": "scaled"}, steps),
                                       ("implicit_euler", {"newton_iters": 100, "velocity_tol": 0.0,
                                                           "friction_updates": 20}, 0)):
        sim = P.build(scene, sets, name, options)
        P.set_stiffness(sim, 100.0, sim.model.group_k.to_numpy().copy())
        sim.set_dt(h)
        sim.integrator.stats()
        sim.advance(steps)
        s = sim.integrator.stats()
        assert s["failed_solve_steps"] == 0 and s["unconverged_steps"] == unconverged, (name, s)
        if not unconverged:
            mu, g = float(sim.terrain.friction[None]), 9.8
            vx = sim.state.v.to_numpy()[:, 0].mean()
            assert abs(vx - (PUSH_SPEED - steps * mu * g * h)) < 0.01 * PUSH_SPEED, vx
    stats = {"steps": 10, "failed_solve_steps": 0, "failed_solve_max_residual_m_s2": 0.0, "energy_clamped_steps": 0}
    lines, meaningless = assess({**stats, "unconverged_steps": int(UNCONVERGED_WARN_SHARE * 10)})
    assert len(lines) == 1 and "5 of 10 steps ended with a residual above 10x" in lines[0] and not meaningless
    assert assess({**stats, "unconverged_steps": 4}) == ([], False)


def test_a_phase_of_its_own_runs_alike_in_both_drivers():
    """The ascent phase is declared once (``PHASES``) and both executors run it: the serial driver
    inlined in its kernel, the parallel one as a launch of its own. Both fail every step and reach
    the same state."""
    import numpy as np

    from physics_helpers import build

    model, terrain = build(n=3, initial_stretch=(1.2, 0.9, 1.0))
    out = []
    for mode in ("serial", "parallel"):
        integ = _Uphill(model, terrain, {"mode": mode})
        assert integ.options.mode == mode
        state = model.state()
        assert integ.advance(state, 0.01, 4) == 4
        assert integ.stats()["failed_solve_steps"] == 4
        out.append(state.numpy())
    assert np.abs(out[0][0] - out[1][0]).max() < 1e-9  # [m]
    assert np.abs(out[0][1] - out[1][1]).max() < 1e-7  # [m/s]: (x - x_n) / h
