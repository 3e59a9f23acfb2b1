"""The memory model (taichi_soft/sim/memory.py) against what runs really allocate and use."""
import math

import pytest
import taichi as ti
from taichi.lang.field import Field
from taichi.lang.matrix import MatrixField

from taichi_soft import runtime
from taichi_soft.sim import memory
from taichi_soft.sim.scene import load_scene

_BYTES = {ti.f64: 8, ti.f32: 4, ti.i32: 4, ti.i64: 8, ti.i8: 1, ti.u8: 1}


def _fields(root):
    """Every distinct Taichi field reachable from ``root`` through taichi_soft objects."""
    seen, found = set(), {}

    def walk(obj):
        if id(obj) in seen:
            return
        seen.add(id(obj))
        if isinstance(obj, Field):
            found[id(obj)] = obj
        elif isinstance(obj, (list, tuple)):
            for o in obj:
                walk(o)
        elif isinstance(obj, dict):
            for o in obj.values():
                walk(o)
        elif type(obj).__module__.startswith("taichi_soft") and hasattr(obj, "__dict__"):
            for o in vars(obj).values():
                walk(o)

    walk(root)
    return list(found.values())


def _field_bytes(f) -> int:
    per = f.n * f.m if isinstance(f, MatrixField) else 1
    return math.prod(f.shape) * per * _BYTES[f.dtype]


def test_field_table_matches_allocated_fields():
    """memory.COMMON and each integrator's declared buffers (Integrator.buffers) count every field
    whose size grows with the body, for every integrator (n = 8: a missing per-particle float would
    be 4 KB, more than all fixed-size fields together)."""
    from taichi_soft.sim.forces import Diagnostics
    from taichi_soft.sim.integrators import REGISTRY, make_integrator, names
    from taichi_soft.sim.lattice import envelope_size
    from taichi_soft.sim.linalg import SkylineCholesky

    from physics_helpers import build

    cases = [(name, "auto", "auto") for name in names()] + [("semi_implicit_euler", "parallel", "auto")]
    cases += [(name, "parallel", "gather") for name in ("semi_implicit_euler", "rk4")]  # the GPU default
    for name, mode, forces in cases:
        # a model per integrator: what one allocates on the model (the adjacency) must not count for the next
        model, terrain = build(n=8, terrain="plane")
        n_p, n_s = model.n_particles, model.n_springs
        assert envelope_size(8) == SkylineCholesky.envelope_size(n_p, model.pairs_np)
        common = [model, model.state(), terrain, Diagnostics(model, terrain)]
        given = {"mode": mode} if REGISTRY[name].implicit else {"mode": mode, "forces": forces}
        fields = _fields(common + [make_integrator(name, model, terrain, given)])
        scaling = [f for f in fields if f.shape and f.shape[0] >= min(n_p, n_s)]
        fixed = sum(_field_bytes(f) for f in fields if f not in scaling)
        sets = ["body.0.n=8"] + [f"solver.{k}={v}" for k, v in given.items()]
        est = memory.estimate(load_scene("plane", sets).data, name, "f64", "cpu",
                              fast_math=runtime.current()["fast_math"])
        assert fixed < 2048, name
        assert abs(sum(_field_bytes(f) for f in scaling) - est["fields"]) <= 64, (name, mode, forces)  # n + 1 sized offsets


def test_step_vectors_start_on_pages():
    """The state, the gather's second state and the RK stage buffers each start on a 4 KiB page
    (allocation.page_aligned_vectors; ti.field put them behind small fields, 56-120 bytes past a
    page, where the gathered step ran 15-25 % slower), hold n elements and are distinct fields."""
    from taichi_soft.sim.allocation import PAGE_BYTES
    from taichi_soft.sim.simulation import Simulation

    @ti.kernel
    def address(f: ti.template()) -> ti.u64:
        return ti.get_addr(f, [0])

    for name in ("semi_implicit_euler", "rk4"):
        sim = Simulation(load_scene("plane", ["body.0.n=7"]), integrator=name,
                         options={"mode": "parallel", "forces": "gather"})
        it = sim.integrator
        vectors = [sim.state.x, sim.state.v] + ([it._xo, it._vo] if it.ping_pong else [])
        vectors += [*getattr(it, "xs", []), *getattr(it, "vs", []), getattr(it, "x_acc", None), getattr(it, "v_acc", None)]
        vectors = [f for f in vectors if f is not None]
        assert len(vectors) == (4 if name == "semi_implicit_euler" else 8)
        starts = [int(address(f)) for f in vectors]
        assert [a % PAGE_BYTES for a in starts] == [0] * len(vectors), name
        assert len(set(starts)) == len(vectors) and all(f.shape == (343,) for f in vectors)  # 343 * 24 B: not a page multiple
        assert sim.advance(5) == 5


def test_estimate_agrees_with_measured_peak():
    """Two sizes, each a fresh one-step CLI run reporting its own peak (VmHWM), within 20 %; and
    the growth between them (the per-particle part of the model, free of the process base)."""
    from taichi_soft.bench.memory import measure_peak

    # n = 100: the growth (about 180 MB with the stencil pass, the default for this run) dwarfs the
    # difference between a run that compiles its kernels and one that finds them in the offline
    # cache (under 20 MB for this integrator).
    rows = [measure_peak(n, "semi_implicit_euler", "f64") for n in (4, 100)]
    for r in rows:
        assert r["peak_bytes"] == pytest.approx(r["estimate_host_bytes"], rel=0.2), r
    small, big = rows
    grew = big["peak_bytes"] - small["peak_bytes"]
    assert grew == pytest.approx(big["estimate_host_bytes"] - small["estimate_host_bytes"], rel=0.2), rows


def test_too_large_scene_is_refused_before_taichi_starts(cli, tmp_path):
    """Fifty 200^3 bodies (400 M particles, ~190 GB with the stencil pass): exit 2, one line with
    the estimate, in seconds (Taichi is not started: no kernel compiles)."""
    body = "[[body]]\nn = 200\n"
    scene = tmp_path / "huge.toml"
    scene.write_text("[sim]\nduration = 0.001\n" + body * 50)
    r = cli("run", "--scene", scene, timeout=120)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "GB of host memory" in lines[0] and "available" in lines[0]
    need = memory.estimate(load_scene(str(scene)).data, None, "f64", "cpu")["host"]
    assert f"{need / 1e9:.1f} GB" in lines[0]


def test_check_fits_and_available(monkeypatch):
    data = load_scene("plane", ["body.0.n=10"]).data
    avail = memory.available_bytes("cpu")
    with open("/proc/meminfo") as f:
        total = int(next(line for line in f if line.startswith("MemTotal")).split()[1]) * 1024
    assert 0 < avail <= total
    assert memory.available_bytes("vulkan") is None
    need = memory.estimate_bytes(data, None, "f64", "cpu")
    memory.check_fits(data, None, "f64", "cpu")  # a 10^3 cube fits anywhere
    monkeypatch.setattr(memory, "_host_available_bytes", lambda: need - 1)
    from taichi_soft.errors import UserError

    with pytest.raises(UserError, match="available") as refused:
        memory.check_fits(data, None, "f64", "cpu")
    # the hint to use f32 only where f32 needs less (with fast math the gather's rows may not)
    f32_smaller = memory.estimate_bytes(data, None, "f32", "cpu") < need
    assert ("--precision f32" in str(refused.value)) == f32_smaller
    no_fm = memory.estimate_bytes(data, None, "f64", "cpu", fast_math=False)
    monkeypatch.setattr(memory, "_host_available_bytes", lambda: no_fm - 1)
    with pytest.raises(UserError, match="--precision f32"):
        memory.check_fits(data, None, "f64", "cpu", fast_math=False)
    # f32 needs less than f64 without fast math (scatter forces; with it, the gather's f32 rows keep
    # (k, kd) copies that f64 reads through the groups); recorded states need more
    assert memory.estimate_bytes(data, None, "f32", "cpu", fast_math=False) < memory.estimate_bytes(
        data, None, "f64", "cpu", fast_math=False)
    assert memory.estimate(data, None, "f64", "cpu", record_states=True)["host"] > need


def test_an_integrator_without_field_counts_is_an_error_not_another_methods_numbers():
    from taichi_soft.errors import UserError

    with pytest.raises(UserError, match="unknown integrator 'toy'"):
        memory.estimate(load_scene("plane").data, "toy", "f64", "cpu")


def test_a_runtime_out_of_field_trees_is_refused_not_crashed(monkeypatch):
    """Taichi's CPU runtime holds 512 SNode trees and frees none; past them it writes out of bounds
    (a segfault). A simulation that could take the runtime past the table is refused instead."""
    from taichi_soft.errors import UserError
    from taichi_soft.sim import allocation
    from taichi_soft.sim.integrators import make_integrator
    from taichi_soft.sim.simulation import Simulation

    scene = load_scene("plane", ["body.0.n=3"])
    before = ti.lang.impl.get_runtime().prog.get_snode_tree_size()
    sim = Simulation(scene)  # room enough: builds
    used = ti.lang.impl.get_runtime().prog.get_snode_tree_size()
    assert used >= before + 8  # the trees it built are counted (semi-implicit Euler's simulation: 8)
    monkeypatch.setattr(allocation, "MAX_TREES", used + allocation.TREES_PER_SIMULATION - 1)
    with pytest.raises(UserError, match="field trees"):
        Simulation(scene)
    with pytest.raises(UserError, match="field trees"):  # the demo's integrator switch
        make_integrator("rk4", sim.model, sim.terrain)
    assert ti.lang.impl.get_runtime().prog.get_snode_tree_size() == used  # refused before allocating
