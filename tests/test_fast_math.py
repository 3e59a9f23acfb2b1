"""Fast math and the fused step kernels: same physics as IEEE arithmetic and as the reference
force pass (to rounding), and the divergence check still sees NaN and inf with fast math on."""
import numpy as np
import pytest
import taichi as ti

from taichi_soft import runtime
from taichi_soft.sim.forces import ForceEvaluator
from taichi_soft.sim.model import Model
from taichi_soft.sim.slabs import graph_ranges
from taichi_soft.sim.integrators import REGISTRY, make_integrator

from physics_helpers import build, simulate, stretched

# Module-level caches hold Taichi objects across tests: one runtime for the module (conftest.py).
pytestmark = pytest.mark.taichi_shared

EXPLICIT = [name for name, cls in REGISTRY.items() if not cls.implicit]
# Butcher tableaus of the textbook methods, written out here (not read from the classes).
TABLEAUS = {"explicit_euler": ([[]], [1.0]), "midpoint": ([[], [0.5]], [0.0, 1.0]),
            "rk4": ([[], [0.5], [0.0, 0.5], [0.0, 0.0, 1.0]], [1 / 6, 1 / 3, 1 / 3, 1 / 6])}


@ti.kernel
def _eval(fe: ti.template(), x: ti.template(), v: ti.template(), a: ti.template()):
    fe.compute(x, v, 1e-3, a)


_REFERENCE = {}


def reference_step(model, terrain, name, x, v, dt, carried=None):
    """One step from the general force pass (group lookups, an acceleration buffer) in numpy;
    ``carried`` (a dict) holds what a method carries from step to step (velocity Verlet's force)."""
    if id(model) not in _REFERENCE:  # one evaluator per model: one compile
        _REFERENCE[id(model)] = (ForceEvaluator(model, terrain, "gather", fused=False), model.state(),
                                 ti.Vector.field(3, float, model.n_particles))
    fe, state, a = _REFERENCE[id(model)]

    def accel(xs, vs):
        state.set(xs, vs)
        _eval(fe, state.x, state.v, a)
        return a.to_numpy().astype(np.float64)

    if name == "semi_implicit_euler":
        vn = v + dt * accel(x, v)
        return x + dt * vn, vn
    if name == "velocity_verlet":  # the force carried from the last step (or a(x_0, v_0)), then a
        an = carried.get("a")     # force at the predicted velocity and one at the velocity it predicts
        an = accel(x, v) if an is None else an
        vh = v + 0.5 * dt * an
        xn = x + dt * vh
        a0 = accel(xn, vh + 0.5 * dt * an)
        carried["a"] = accel(xn, vh + 0.5 * dt * a0)  # the whole force again: the fused step redoes the dampers only
        return xn, vh + 0.5 * dt * carried["a"]
    A, b = TABLEAUS[name]
    ks = []
    for s in range(len(b)):
        xs, vs = x.copy(), v.copy()
        for j, c in enumerate(A[s]):
            xs += dt * c * ks[j][0]
            vs += dt * c * ks[j][1]
        ks.append((vs, accel(xs, vs)))
    return x + dt * sum(c * k[0] for c, k in zip(b, ks)), v + dt * sum(c * k[1] for c, k in zip(b, ks))


# (launch mode, force strategy, integrators): every strategy, both scatter launch modes with all
# methods, ping-pong (one-stage methods with gathered forces) both ways.
FUSED_CASES = [("serial", "scatter", EXPLICIT), ("parallel", "scatter", ["explicit_euler", "semi_implicit_euler", "velocity_verlet", "rk4"]),
               ("parallel", "gather", ["explicit_euler", "semi_implicit_euler", "velocity_verlet", "midpoint"]),
               ("serial", "gather", ["semi_implicit_euler", "velocity_verlet"]),
               ("serial", "per_spring", ["velocity_verlet", "rk4"]), ("parallel", "per_spring", ["velocity_verlet"])]


@pytest.mark.parametrize("mode, forces, names", FUSED_CASES, ids=[f"{m}-{f}" for m, f, _ in FUSED_CASES])
def test_fused_steps_match_the_reference_force_pass(mode, forces, names):
    """Fused steps against steps built from ``ForceEvaluator.compute`` (group lookups, an
    acceleration buffer): equal to f64 rounding. A 6^3 cube spans three scatter slabs. Advancing
    1 then 2 steps checks that ping-pong leaves the state in place for odd and even counts."""
    model, terrain = build(n=6, size=1.0, gravity=(0.0, -9.8, 0.0))
    rng = np.random.default_rng(5)
    x0 = stretched(model)
    v0 = rng.standard_normal(x0.shape)
    dt = 2e-3
    for name in names:
        integ = make_integrator(name, model, terrain, {"mode": mode, "forces": forces})
        state = model.state()
        state.set(x0, v0)
        x, v, carried = x0, v0, {}
        for steps in (1, 2):
            for _ in range(steps):
                x, v = reference_step(model, terrain, name, x, v, dt, carried)
            assert integ.advance(state, dt, steps) == steps
            xe, ve = state.numpy()
            np.testing.assert_allclose(xe, x, rtol=0, atol=1e-12, err_msg=f"{name} {mode} {forces} x after {steps}")
            np.testing.assert_allclose(ve, v, rtol=0, atol=1e-9, err_msg=f"{name} {mode} {forces} v after {steps}")


def _check_slabs(pairs, first, ranges, n_particles):
    """Every spring in exactly one slab; within the even (odd) slabs no particle is an end of
    springs of two different slabs."""
    ids = np.concatenate([np.arange(s, e) for s, e in ranges]) if len(ranges) else np.zeros(0, int)
    assert np.array_equal(np.sort(ids), np.arange(len(pairs)))
    for parity in (0, 1):
        owner = np.full(n_particles, -1)
        for slab in range(parity, len(first) - 1, 2):
            ends = np.unique(np.concatenate([pairs[s:e].ravel() for s, e in ranges[first[slab]:first[slab + 1]]] or
                                            [np.zeros(0, int)]))
            assert (owner[ends] == -1).all(), f"slab {slab} shares a particle with slab {owner[ends].max()}"
            owner[ends] = slab
    return len(first) - 1


def test_scatter_slabs_of_one_parity_share_no_particle():
    """The parallel scatter's race freedom, on the springs in the model's own order: lattice
    bodies of several sizes (rotated: springs at every angle) in one model, and a random graph."""
    from taichi_soft.sim.bodies import BodySpec
    from taichi_soft.sim.builder import ModelBuilder

    builder = ModelBuilder()
    for k, n in enumerate((2, 3, 7, 8)):
        builder.add_cube(BodySpec(n=n, size=2.0, center=(5.0 * k, 0.0, 0.0), rotation_axis=(1.0, 2.0, 0.5),
                                  rotation_degrees=37.0 * k))
    model = builder.finalize()
    first, ranges = model.slab_ranges()
    assert _check_slabs(model.pairs_np, first, ranges, model.n_particles) == 4  # ceil(8 / 2)
    assert len(ranges) <= 16 * 4 * 4  # one range per offset, slab and body: nothing per spring

    rng = np.random.default_rng(5)
    x0 = rng.random((40, 3)) * [10.0, 1.0, 1.0]
    near = [(a, b) for a in range(40) for b in range(40) if a != b and abs(x0[a, 0] - x0[b, 0]) < 1.5]
    pairs = np.array(near)[rng.random(len(near)) < 0.3]
    first, ranges = graph_ranges(x0, pairs)
    assert _check_slabs(pairs, first, ranges, 40) >= 4


def test_scatter_of_any_graph_matches_the_reference():
    """A model made from host arrays (no lattice) takes parallel scatter steps equal to the
    reference force pass."""
    rng = np.random.default_rng(2)
    n = 30
    x0 = rng.random((n, 3)) * [6.0, 1.0, 1.0]
    pairs = np.array([(a, b) for a in range(n) for b in range(a + 1, n) if np.linalg.norm(x0[a] - x0[b]) < 1.0])
    rest = np.linalg.norm(x0[pairs[:, 0]] - x0[pairs[:, 1]], axis=1) * 0.9
    model = Model(x0=x0, v0=np.zeros_like(x0), mass=np.ones(n), pairs=pairs, rest=rest, group=np.zeros(len(pairs)),
                  group_k=[500.0], group_kd=[2.0], gravity=(0.0, -9.8, 0.0), bodies=[])
    from taichi_soft.sim.contact.terrain import make_terrain

    terrain = make_terrain("none", n, {})
    integ = make_integrator("semi_implicit_euler", model, terrain, {"mode": "parallel", "forces": "scatter"})
    assert integ.forces.n_slabs >= 4
    state = model.state()
    x, v = x0.copy(), np.zeros_like(x0)
    for _ in range(3):
        x, v = reference_step(model, terrain, "semi_implicit_euler", x, v, 1e-3)
    assert integ.advance(state, 1e-3, 3) == 3
    np.testing.assert_allclose(state.numpy()[0], x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(state.numpy()[1], v, rtol=0, atol=1e-9)


@pytest.mark.parametrize("mode, forces", [("parallel", "scatter"), ("serial", "gather")])
def test_stiffness_change_reaches_the_fused_kernels(mode, forces):
    """k and kd are copied next to the springs (or into the gather's row slots); a change through
    the model, or written straight into its fields, must act on the next step."""
    model, terrain = build(n=3, size=1.0)
    x0 = stretched(model)
    integ = make_integrator("semi_implicit_euler", model, terrain, {"mode": mode, "forces": forces})
    state = model.state()
    state.set(x0, np.zeros_like(x0))
    integ.advance(state, 1e-3, 1)
    model.set_spring_params(0, "stretch", k=8000.0)
    model.group_kd.from_numpy(model.group_kd.to_numpy() * 2)  # a direct field write: the kernels read it each step
    x1, v1 = state.numpy()
    _, vr = reference_step(model, terrain, "semi_implicit_euler", x1, v1, 1e-3)
    integ.advance(state, 1e-3, 1)
    np.testing.assert_allclose(state.numpy()[1], vr, rtol=0, atol=1e-9)


def _scene():
    model, terrain = build(n=4, size=1.5, gravity=(0.0, -9.8, 0.0), terrain="plane",
                           geometry={"point": [0.0, -0.9, 0.0]})
    return model, terrain, stretched(model)


def test_fast_math_same_physics_to_rounding():
    """50 steps of a stretched cube touching the plane, fast math on and off: the same final state
    to a few hundred ulps of the positions (f64: 1e-12 m on ~1 m; f32: 2e-5 m)."""
    try:
        for precision, tol, name, mode in (("f64", 1e-12, "semi_implicit_euler", "parallel"),
                                           ("f32", 2e-5, "midpoint", "serial")):
            final = []
            for fast_math in (False, True):
                runtime.init("cpu", precision, fast_math=fast_math)
                model, terrain, x0 = _scene()
                final.append(simulate(model, terrain, name, 1e-3, 50, x0, np.zeros_like(x0), {"mode": mode}))
            assert final[0][2] == final[1][2] == 50
            np.testing.assert_allclose(final[1][0], final[0][0], rtol=0, atol=tol, err_msg=f"{precision} {name}")
    finally:
        runtime.init("cpu", "f64")


def test_divergence_caught_with_fast_math_nan_and_inf():
    """A NaN or an infinite velocity injected at one particle stops the run at its first step,
    fast math on, f64 and f32, serial and parallel (ping-pong) launches and a multi-stage method."""
    try:
        for precision in ("f64", "f32"):
            runtime.init("cpu", precision, fast_math=True)
            model, terrain, x0 = _scene()
            cases = [("semi_implicit_euler", "serial"), ("semi_implicit_euler", "parallel")]
            if precision == "f64":  # a multi-stage method once (its compile is the slow part)
                cases.append(("rk4", "parallel"))
            for name, mode in cases:
                integ = make_integrator(name, model, terrain, {"mode": mode})
                state = model.state()
                for inject in (np.nan, np.inf, -np.inf):
                    v0 = np.zeros_like(x0)
                    v0[5, 1] = inject
                    state.set(x0, v0)
                    integ.reset()
                    assert integ.advance(state, 1e-3, 5) == 1, (precision, inject, name, mode)
                    assert integ.diverged
    finally:
        runtime.init("cpu", "f64")


def test_cli_divergence_exit_3_with_fast_math(cli, tmp_path):
    """An infinite speed (1e300 m/s squared overflows f64) through the command line: exit 3."""
    r = cli("run", "--fast-math", "--set", "body.0.n=3", "--set", "body.0.velocity=[1e300, 0.0, 0.0]",
            "--duration", "0.01", "--summary", tmp_path / "s.json")
    assert r.returncode == 3, r.stderr
    assert "diverged at t =" in r.stderr


def test_gather_rows_zero_length_springs_and_repeats():
    """The gather's padded rows (rows.py) with fast math, f32: each particle's row holds its
    springs once, then padding (itself, rest 0); a zero-length spring (two particles moved onto
    each other) gives finite motion and no divergence; a repeat run is bit-identical."""
    try:
        runtime.init("cpu", "f32", fast_math=True)
        model, terrain = build(n=3, size=1.0)
        x0 = model.x0_np.copy()
        x0[1] = x0[0]
        finals = []
        for _ in range(2):
            integ = make_integrator("semi_implicit_euler", model, terrain, {"mode": "serial", "forces": "gather"})
            state = model.state()
            state.set(x0, np.zeros_like(x0))
            assert integ.advance(state, 1e-4, 5) == 5 and not integ.diverged
            finals.append(state.numpy())
            assert np.all(np.isfinite(finals[-1][0])) and np.all(np.isfinite(finals[-1][1]))
        np.testing.assert_array_equal(finals[0][0], finals[1][0])
        np.testing.assert_array_equal(finals[0][1], finals[1][1])
        other, rest = integ.forces.rows.numpy_rows()
        pairs = model.pairs_np
        for i in range(model.n_particles):
            mine = sorted(np.concatenate([pairs[pairs[:, 0] == i, 1], pairs[pairs[:, 1] == i, 0]]))
            used = other[i, : len(mine)]
            assert sorted(used) == mine
            assert np.all(other[i, len(mine):] == i) and np.all(rest[i, len(mine):] == 0)
    finally:
        runtime.init("cpu", "f64")
