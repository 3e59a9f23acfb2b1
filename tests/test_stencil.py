"""The stencil force pass (solver.forces = stencil): the same forces as the stored-spring passes,
no spring stored and none counted by the memory estimate, no NaN from zero-length springs, NaN
caught under fast math, run-time stiffness, bit-identical repeats, mesh bodies through the presence
mask, the Vulkan backend."""
import numpy as np
import pytest

from taichi_soft import runtime
from taichi_soft.errors import UserError
from taichi_soft.sim import memory, stencil
from taichi_soft.sim.footprint import MODEL_SPRINGS
from taichi_soft.sim.integrators import REGISTRY
from taichi_soft.sim.scene import load_scene

from backend_probe import run_on_backends
from conftest import ROOT, restart_taichi
from test_memory import _field_bytes, _fields

# velocity_verlet refuses the stencil (its damper corrector reads the stored springs: tested below)
EXPLICIT = [name for name, cls in REGISTRY.items() if not cls.implicit and name != "velocity_verlet"]
# The default cube, started deformed and turned so that it lands on an edge within the second:
# every kind of spring and damper works, and the plane's contact too.
DEFORMED = ["body.0.initial_stretch=[1.2,0.85,1.1]", "body.0.center=[0,3.2,0]"]
DT = 5e-4  # [s]: stable for every explicit method on the default cube (velocity Verlet's limit ~1 ms)
# Positions after 1 s [m]: the stencil sums a particle's springs in the gather's row order, so
# with IEEE arithmetic the two agree bit for bit; with fast math the compiler may reorder each
# sum differently per kernel (a few ulps per step, grown by the landing).
TOL_FAST_MATH = 1e-9


def _final(make_sim, name, forces, sets=()):
    sim = make_sim("plane", DEFORMED + list(sets), integrator=name, dt=DT, options={"forces": forces})
    assert sim.advance(int(round(1.0 / DT))) == int(round(1.0 / DT))
    return sim


@pytest.mark.parametrize("name", EXPLICIT)
def test_same_answers_as_the_stored_spring_passes(make_sim, name):
    """Every explicit method, 1 s on the default cube: bit-identical to the gather (IEEE
    arithmetic, the suite's setting), to rounding (1e-12 m) to the scatter, and the cube moved."""
    x0 = None
    out = {}
    for forces in ("stencil", "gather", "scatter"):
        sim = _final(make_sim, name, forces)
        x0 = sim.model.x0_np if x0 is None else x0
        out[forces] = sim.state.numpy()[0]
        assert sim.model.springs_stored() == (forces != "stencil")
    assert np.array_equal(out["stencil"], out["gather"])
    assert np.abs(out["stencil"] - out["scatter"]).max() <= 1e-12
    assert np.abs(out["stencil"] - x0).max() > 1.0  # it fell and landed


def test_same_answers_with_fast_math(make_sim, taichi_runtime):
    """With fast math (the command line's default) the stencil and the gather agree to
    TOL_FAST_MATH after 1 s, for the one- and the four-stage method."""
    try:
        runtime.init("cpu", "f64", fast_math=True)
        for name in ("semi_implicit_euler", "rk4"):
            a = _final(make_sim, name, "stencil").state.numpy()[0]
            b = _final(make_sim, name, "gather").state.numpy()[0]
            assert np.abs(a - b).max() <= TOL_FAST_MATH, name
    finally:
        restart_taichi(taichi_runtime)


def test_repeat_runs_are_bit_identical(make_sim):
    sim = _final(make_sim, "semi_implicit_euler", "stencil")
    first = sim.state.numpy()
    sim.reset()
    sim.integrator.reset()
    assert sim.advance(int(round(1.0 / DT))) == int(round(1.0 / DT))
    again = sim.state.numpy()
    assert all(np.array_equal(a, b) for a, b in zip(first, again))


def test_memory_estimate_counts_no_springs(make_sim):
    """The fields a stencil run allocates are what the estimate says, the model's springs not among
    them: per particle the model's masses, the state and the ping-pong state (8 vectors + 2 reals)."""
    n = 8
    for name in EXPLICIT:
        sim = make_sim("plane", [f"body.0.n={n}"], integrator=name, options={"forces": "stencil"})
        n_p = sim.model.n_particles
        fields = _fields([sim.model, sim.state, sim.terrain, sim.diagnostics, sim.integrator])
        scaling = sum(_field_bytes(f) for f in fields if f.shape and f.shape[0] >= n_p)
        data = load_scene("plane", [f"body.0.n={n}", "solver.forces=stencil"]).data
        est = memory.estimate(data, name, "f64", "cpu", fast_math=False)
        assert scaling == est["fields"], name
        stored = memory.estimate(load_scene("plane", [f"body.0.n={n}", "solver.forces=gather"]).data,
                                 name, "f64", "cpu", fast_math=False)
        assert stored["fields"] - est["fields"] >= MODEL_SPRINGS.bytes(n_p, sim.model.n_springs, 8)
        if name == "semi_implicit_euler":
            assert est["fields"] == n_p * (2 + 6 + 6) * 8


def test_zero_length_springs_give_no_nan(make_sim):
    """Every particle at one point: every spring has length 0, so no force (no NaN): one step of
    free fall, v = g dt."""
    for name in EXPLICIT:
        sim = make_sim("plane", ["body.0.n=4"], integrator=name, dt=1e-3, options={"forces": "stencil"})
        x, v = sim.state.numpy()
        sim.state.set(np.broadcast_to(x.mean(axis=0), x.shape).copy(), np.zeros_like(v))
        assert sim.advance(1) == 1 and not sim.integrator.diverged, name
        x, v = sim.state.numpy()
        assert np.isfinite(x).all() and np.isfinite(v).all()
        assert np.allclose(v, [0.0, -9.8e-3, 0.0], rtol=0, atol=1e-12), name


def test_nan_caught_under_fast_math(make_sim, taichi_runtime):
    try:
        runtime.init("cpu", "f64", fast_math=True)
        for bad in (np.nan, np.inf):
            sim = make_sim("plane", ["body.0.n=4"], integrator="semi_implicit_euler", options={"forces": "stencil"})
            x, v = sim.state.numpy()
            v[5, 1] = bad
            sim.state.set(x, v)
            sim.advance(3)
            assert sim.integrator.diverged, bad
    finally:
        restart_taichi(taichi_runtime)


def test_run_time_stiffness_acts(make_sim):
    """Stiffness changed after the first steps (no recompile) gives what a cube built with it gives."""
    changed = make_sim("plane", DEFORMED, integrator="semi_implicit_euler", dt=DT, options={"forces": "stencil"})
    changed.advance(1)  # compiled and stepped with the scene's stiffness
    changed.reset()
    changed.integrator.reset()
    for kind in ("stretch", "shear", "bend"):
        changed.model.set_spring_params(0, kind, k=5000.0, damping=20.0)
    changed.advance(400)
    sets = [f"body.0.{kind}={{k=5000.0,damping=20.0}}" for kind in ("stretch", "shear", "bend")]
    built = make_sim("plane", DEFORMED + sets, integrator="semi_implicit_euler", dt=DT, options={"forces": "stencil"})
    built.advance(400)
    plain = make_sim("plane", DEFORMED, integrator="semi_implicit_euler", dt=DT, options={"forces": "stencil"})
    plain.advance(400)
    assert np.array_equal(changed.state.numpy()[0], built.state.numpy()[0])
    assert np.abs(changed.state.numpy()[0] - plain.state.numpy()[0]).max() > 1e-3


# A cube and a mesh body in one scene (the scene's middle body made a torus): the mask path for both.
MIXED = ["body.0.n=6", "body.2.n=4", 'body.1.shape="mesh"', f'body.1.mesh="{ROOT / "scenes" / "meshes" / "torus.obj"}"',
         "body.1.n=12"]


@pytest.mark.parametrize("scene,sets,steps", [("blob", [], 300), ("three_cubes", MIXED, 100)], ids=["mesh", "cube_and_mesh"])
def test_mesh_bodies_same_answers_as_the_gather(make_sim, scene, sets, steps):
    """A mesh body (a clipped lattice, read through the presence mask), alone and beside cubes:
    0.3 s (0.1 s) of semi-implicit Euler bit-identical to the gather (IEEE arithmetic), no spring
    stored, the same spring energy (to the f64 sum's rounding), and the bodies moved. Both scenes have
    particles with all 32 neighbours (the unchecked loop) and particles near a clipped face."""
    out = {}
    for forces in ("stencil", "gather"):
        sim = make_sim(scene, sets, integrator="semi_implicit_euler", dt=1e-3, options={"forces": forces})
        assert sim.advance(steps) == steps
        assert sim.model.springs_stored() == (forces != "stencil")
        out[forces] = sim.state.numpy()[0], sim.diagnostics.compute(sim.state)["spring_energy"]
    assert np.array_equal(out["stencil"][0], out["gather"][0])
    assert out["stencil"][1] == pytest.approx(out["gather"][1], rel=1e-9) and out["gather"][1] > 0
    assert np.abs(out["stencil"][0] - sim.model.x0_np).max() > 0.04  # free fall alone: 0.049 m in 0.1 s


def test_mesh_memory_estimate_counts_the_mask(make_sim):
    """A mesh body's stencil run allocates what the estimate says: the model's masses, the state, the
    ping-pong state and the presence mask (a particle's lattice point, a point's particle of the
    lattice padded by two points on every side: i32 each), no spring; below the gather's estimate."""
    sim = make_sim("torus", integrator="semi_implicit_euler", options={"forces": "stencil"})
    n_p = sim.model.n_particles
    points = np.prod(np.array(sim.model.bodies[0].mesh.grid.shape) + 2 * stencil.INTERIOR_MARGIN)
    fields = _fields([sim.model, sim.state, sim.terrain, sim.diagnostics, sim.integrator, sim.model.stencil])
    scaling = sum(_field_bytes(f) for f in fields if f.shape and f.shape[0] >= n_p)
    data = load_scene("torus", ["solver.forces=stencil"]).data
    est = memory.estimate(data, "semi_implicit_euler", "f64", "cpu", fast_math=False)
    assert scaling == est["fields"] == n_p * (2 + 6 + 6) * 8 + (n_p + points) * 4
    gather = memory.estimate(load_scene("torus", ["solver.forces=gather"]).data, "semi_implicit_euler", "f64", "cpu",
                             fast_math=False)
    assert gather["fields"] > est["fields"]


def test_velocity_verlet_refuses_the_stencil_before_any_work():
    """Its damper corrector reads the stored springs: one clear line, not a Taichi compile error."""
    data = load_scene("plane", ["solver.forces=stencil"]).data
    with pytest.raises(UserError, match="velocity_verlet: solver.forces = stencil"):
        memory.estimate(data, "velocity_verlet", "f64", "cpu")


def test_vulkan_stencil_matches_the_cpu():
    """The stencil pass on Vulkan (Mesa's lavapipe runs it on the CPU here), f32: the deformed n = 6
    cube after 30 steps of 1 ms lies within 1e-4 m of the CPU backend's, and its springs moved it
    well away from free fall (so the agreement is not that of two empty force passes)."""
    steps, dt = 30, 1e-3
    case = dict(sets=DEFORMED + ["body.0.n=6"], integrator="semi_implicit_euler", dt=dt, steps=steps,
                options={"forces": "stencil"})
    out = {arch: runs[0] for arch, runs in run_on_backends([case], ("vulkan", "cpu")).items()}
    assert all(r["steps"] == steps and not r["diverged"] for r in out.values())
    assert out["vulkan"]["arch"] == "vulkan" and out["vulkan"]["started"] == "vulkan", out["vulkan"]["started"]
    assert out["cpu"]["arch"] == "cpu"
    assert out["vulkan"]["strategy"] == out["cpu"]["strategy"] == "stencil"
    gpu, cpu = np.array(out["vulkan"]["x"]), np.array(out["cpu"]["x"])
    x0 = np.array(out["cpu"]["x0"])
    assert np.abs(gpu - cpu).max() <= 1e-4, np.abs(gpu - cpu).max()
    free_fall = x0 + np.array([0.0, -9.8, 0.0]) * dt * dt * steps * (steps + 1) / 2  # semi-implicit Euler's
    assert np.abs(cpu - free_fall).max() > 1e-2


def test_auto_picks_the_stencil_for_parallel_f64_cube_steps_with_fast_math():
    """forces = auto on a CPU with fast math: the stencil for cube bodies stepped in parallel launches
    in f64 (docs/decisions/auto-picks-the-stencil.md); the gather in f32, for serial launches, mesh
    bodies, velocity Verlet and GPUs; the scatter without fast math."""
    from taichi_soft.sim.footprint import Counts
    from taichi_soft.sim.integrators import integrator_class

    big, small = Counts(64000, 10**6, lattice=True), Counts(8000, 10**5, lattice=True)
    mesh = Counts(64000, 10**6, lattice=False)
    euler = integrator_class("semi_implicit_euler")
    assert euler.configure({}, "cpu", True, big).forces == "stencil"
    assert integrator_class("rk4").configure({}, "cpu", True, big).forces == "stencil"
    assert euler.configure({"mode": "parallel"}, "cpu", True, small).forces == "stencil"
    assert euler.configure({}, "cpu", True, small).forces == "gather"
    assert euler.configure({}, "cpu", True, mesh).forces == "gather"
    assert euler.configure({}, "cpu", True, Counts(64000, 10**6, lattice=True, real_bytes=4)).forces == "gather"
    assert integrator_class("velocity_verlet").configure({}, "cpu", True, big).forces == "gather"
    assert euler.configure({}, "cuda", True, big).forces == "gather"
    assert euler.configure({}, "cpu", False, big).forces == "scatter"


def test_default_run_estimate_stores_no_springs_at_n40():
    """The default run of the n = 40 cube (CPU, fast math, f64) stores no springs: its fields are
    the masses, the state and the ping-pong state, 112 bytes per particle."""
    data = load_scene("plane", ["body.0.n=40"]).data
    est = memory.estimate(data, None, "f64", "cpu", fast_math=True)
    assert est["fields"] == est["particles"] * (2 + 6 + 6) * 8
    assert memory.estimate(data, None, "f32", "cpu", fast_math=True)["fields"] > est["fields"]  # f32: the gather
