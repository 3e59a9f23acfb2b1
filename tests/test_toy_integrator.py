"""The goal: an integrator written in one file (options, buffer table, step) is listed by `list`,
accepted by `run`, estimated by the memory check and swept by the benchmark, with no other module
touched: everything the product needs to know of it, it declares itself.

``toy_euler`` is symplectic Euler taking ``substeps`` steps of dt / substeps per step, keeping each
particle's last acceleration (its own field, in its own table). It allows no gathered forces (its
step updates the state in place), so its ``resolve`` makes ``forces = auto`` the scatter.
"""
import json
from dataclasses import dataclass

import numpy as np
import pytest
import taichi as ti

from taichi_soft.sim.footprint import VEC, per_particle
from taichi_soft.sim.integrators import REGISTRY, make_integrator
from taichi_soft.sim.integrators import linear_stability
from taichi_soft.sim.integrators.base import ExplicitConfig, Integrator, register
from taichi_soft.sim.integrators.options import choice, int_at_least, option


@ti.data_oriented
class ToyEuler(Integrator):
    """v += h a(x, v); x += h v, ``substeps`` times per step of dt (h = dt / substeps)."""

    name = "toy_euler"
    order = 1
    force_evals = 1
    description = "toy symplectic Euler with substeps (a test's integrator)"
    BUFFERS = {"last_accel": per_particle("the last substep's acceleration [m/s^2]", VEC)}  # allocated by the base
    # With its default single substep it is symplectic Euler, whose linear stability it shares.
    amplification = staticmethod(linear_stability.symplectic_euler)
    sweep_dt_cap = 2e-3

    @dataclass(frozen=True)
    class Config(ExplicitConfig):
        forces: str = choice("auto", ("auto", "scatter", "per_spring"),
                             "force strategy; auto: scatter (in-place steps cannot read gathered forces)")
        substeps: int = option(1, int_at_least(1), "an integer >= 1", "symplectic Euler steps per step")

        def resolve(self, arch, fast_math, counts):
            out = self.but(forces="scatter") if self.forces == "auto" else self
            return ExplicitConfig.resolve(out, arch, fast_math, counts)

    @ti.func
    def _step_body(self, x: ti.template(), v: ti.template(), dt, step):
        h = dt / self.options.substeps
        for _ in ti.static(range(self.options.substeps)):
            self.forces.spring_pass(x, v)
            for i in range(self.n):
                a = self.forces.accel(x, v, i, h)
                self.last_accel[i] = a
                vn = v[i] + h * a
                self._finish(i, x, v, x[i] + h * vn, vn, step)


@pytest.fixture
def toy(monkeypatch):
    """ToyEuler registered for one test (REGISTRY is restored afterwards)."""
    monkeypatch.setitem(REGISTRY, ToyEuler.name, ToyEuler)
    return ToyEuler


def test_free_fall_is_symplectic_euler_to_round_off(toy):
    """A cube thrown in vacuum moves rigidly: after N steps of h, symplectic Euler gives exactly
    x0 + v0 t + g t (t + h) / 2 (the parabola plus g h t / 2), here with h = dt / 2."""
    from physics_helpers import build

    g = np.array([0.0, -9.8, 0.0])
    model, terrain = build(n=3, gravity=tuple(g))
    integ = make_integrator("toy_euler", model, terrain, {"substeps": 2})
    assert integ.options.forces == "scatter" and integ.options.mode == "serial"
    v0 = np.array([1.0, 2.0, -0.5])
    state = model.state()
    state.set(model.x0_np, np.tile(v0, (model.n_particles, 1)))
    dt, steps = 0.002, 100  # h = 1 ms: below the springs' stability limit (their round-off forces stay round-off)
    assert integ.advance(state, dt, steps) == steps
    x, v = state.numpy()
    t, h = dt * steps, dt / 2
    expected = model.x0_np + v0 * t + g * t * (t + h) / 2
    assert np.abs(x - expected).max() < 1e-12
    assert np.abs(v - (v0 + g * t)).max() < 1e-12
    assert np.abs(x - (model.x0_np + v0 * t + g * t * t / 2)).max() == pytest.approx(9.8 * h * t / 2, rel=1e-9)
    assert np.allclose(integ.last_accel.to_numpy(), g, atol=1e-9)


def test_list_and_run_take_it(toy, monkeypatch, capsys, tmp_path):
    from taichi_soft import cli
    from taichi_soft.commands import common

    assert cli.main(["list"]) == 0
    assert "toy_euler              order 1, toy symplectic Euler with substeps" in capsys.readouterr().out

    monkeypatch.setattr(common, "start_taichi", lambda args: None)  # conftest's runtime is running
    summary = tmp_path / "s.json"
    code = cli.main(["run", "--set", "body.0.n=3", "--set", "solver.substeps=2", "--integrator", "toy_euler",
                     "--dt", "0.002", "--duration", "0.05", "--summary", str(summary)])
    assert code == 0, capsys.readouterr().err
    s = json.loads(summary.read_text())
    assert s["integrator"] == "toy_euler" and s["steps"] == 25, s
    # a bad value of its own option is refused with its own documentation
    assert cli.main(["run", "--set", "solver.substeps=0", "--integrator", "toy_euler", "--duration", "0.01"]) == 2
    assert "solver.substeps = 0: must be an integer >= 1 (symplectic Euler steps per step)" in capsys.readouterr().err


def test_the_memory_check_estimates_it_from_its_own_table(toy):
    """The estimate's fields are what a real toy run allocates (as tests/test_memory.py measures),
    and exceed semi-implicit Euler's (the same force pass) by its own table, 3 reals per particle."""
    from taichi_soft import runtime
    from taichi_soft.sim import memory
    from taichi_soft.sim.forces import Diagnostics
    from taichi_soft.sim.scene import load_scene

    from physics_helpers import build
    from test_memory import _field_bytes, _fields

    model, terrain = build(n=8, terrain="plane")
    integ = make_integrator("toy_euler", model, terrain, {"substeps": 3})
    # (the walk enters taichi_soft objects only: the toy's attributes are given to it one by one)
    fields = _fields([model, model.state(), terrain, Diagnostics(model, terrain), *vars(integ).values()])
    allocated = sum(_field_bytes(f) for f in fields if f.shape and f.shape[0] >= model.n_particles)
    data = load_scene("plane", ["body.0.n=8", "solver.substeps=3"]).data
    fast_math = runtime.current()["fast_math"]
    est = memory.estimate(data, "toy_euler", "f64", "cpu", fast_math=fast_math)
    assert abs(allocated - est["fields"]) <= 64
    semi = memory.estimate(data, "semi_implicit_euler", "f64", "cpu", fast_math=False)
    assert est["fields"] - semi["fields"] == 3 * 8 * model.n_particles
    assert est["host"] - est["fields"] == semi["host"] - semi["fields"] + ToyEuler.BASE_BYTES - REGISTRY[
        "semi_implicit_euler"].BASE_BYTES
    memory.check_fits(data, "toy_euler", "f64", "cpu")


def test_the_accuracy_sweep_measures_it(toy):
    """The accuracy study's pieces (what its tasks run, in this process: the bench's task workers are
    fresh processes, where this test's registration does not exist): first order, and with one
    substep the same answers as semi-implicit Euler, the same method."""
    from taichi_soft.bench import accuracy

    dts = [0.002, 0.001]
    ref, dt_ref = accuracy.reference("smooth", min(dts), frames=2)
    rows = {name: accuracy.measure_integrator("smooth", name, dts, ref, dt_ref, frames=2, repeats=1)
            for name in ("toy_euler", "semi_implicit_euler")}
    toy_rows = rows["toy_euler"]
    assert [r["integrator"] for r in toy_rows] == ["toy_euler"] * 2 and not any(r["diverged"] for r in toy_rows)
    assert [r["error_final"] for r in toy_rows] == [r["error_final"] for r in rows["semi_implicit_euler"]]
    assert 0.8 < accuracy.fitted_order(toy_rows, "toy_euler") < 1.3


def test_a_method_without_its_facts_is_refused(toy):
    """A registered method declares its stability (the divergence hint) and its sweep's largest step:
    without them ``register`` refuses it by name instead of degrading those silently."""
    bare = type("Bare", (ToyEuler,), {"name": "bare", "amplification": None, "sweep_dt_cap": None})
    with pytest.raises(TypeError, match="'bare' .*does not declare amplification, sweep_dt_cap"):
        register(bare)
    assert "bare" not in REGISTRY
    assert register(ToyEuler) is ToyEuler  # the toy declares both


def test_the_divergence_hint_knows_its_stability_limit(toy):
    """The hint's limit for the toy is its own matrix's, here semi-implicit Euler's (one substep)."""
    from physics_helpers import build

    model, _ = build(n=4)
    w2, ratios = linear_stability.scene_modes(model)
    limit = linear_stability.stable_limit("toy_euler", w2, ratios)
    assert limit == linear_stability.stable_limit("semi_implicit_euler", w2, ratios)
    assert 0 < limit < 2.1 / w2 ** 0.5  # symplectic Euler: h w < 2 without dampers
