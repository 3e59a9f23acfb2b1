"""The command line through a subprocess: exit codes, summary and states contents, bad input."""
import json

import numpy as np
import pytest

from taichi_soft.sim.scene import load_scene
from taichi_soft.sim.scene_overrides import apply_overrides, parse_value
from taichi_soft.errors import UserError
from taichi_soft.sim.simulation import frame_steps

SMALL = ["--set", "body.0.n=4", "--set", "body.0.size=1.5", "--duration", "0.2"]


def test_run_writes_summary_and_states(cli, tmp_path):
    summary, states = tmp_path / "s.json", tmp_path / "s.npz"
    r = cli("run", "--scene", "plane", "--integrator", "rk4", *SMALL, "--summary", summary, "--states", states)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    s = json.loads(summary.read_text())
    for key in ("scene", "integrator", "dt", "steps", "sim_time", "particles", "springs", "diverged", "diverged_at",
                "wall_seconds", "steps_per_second", "final"):
        assert key in s
    assert s["scene"] == "plane" and s["integrator"] == "rk4" and s["steps"] == 200 and s["particles"] == 64
    assert s["springs"] == {"stretch": 144, "shear": 324, "bend": 96}
    assert s["diverged"] is False and s["diverged_at"] is None
    assert s["sim_time"] == pytest.approx(0.2)
    for key in ("center_of_mass", "kinetic_energy", "potential_energy", "max_speed", "min_terrain_distance"):
        assert key in s["final"]
    d = np.load(states)
    assert d["x"].dtype == np.float64 and d["x"].shape[1:] == (64, 3) and d["v"].shape == d["x"].shape
    assert d["t"][0] == 0.0 and d["t"][-1] == pytest.approx(0.2)
    # 30 fps over 0.2 s: frames at 0, 1/30, ..., 6/30 = 0.2
    assert len(d["t"]) == 7
    np.testing.assert_allclose(d["x"][-1].mean(axis=0), s["final"]["center_of_mass"], atol=1e-12)


def test_states_in_f32(cli, tmp_path):
    states = tmp_path / "s.npz"
    r = cli("run", *SMALL, "--precision", "f32", "--states", states)
    assert r.returncode == 0, r.stderr
    assert np.load(states)["x"].dtype == np.float32


def test_divergence_exit_3_and_outputs(cli, tmp_path):
    summary, states = tmp_path / "s.json", tmp_path / "s.npz"
    r = cli("run", "--scene", "plane", "--integrator", "explicit_euler", "--dt", "0.01", *SMALL[:4],
            "--duration", "2", "--summary", summary, "--states", states)
    assert r.returncode == 3
    assert "diverged at t =" in r.stderr and "explicit_euler" in r.stderr and "--dt" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert f"summary: {summary}" in r.stdout and f"states: {states}" in r.stdout
    s = json.loads(summary.read_text())
    assert s["diverged"] is True and 0 < s["diverged_at"] < 2
    d = np.load(states)
    assert len(d["t"]) >= 1 and np.all(np.isfinite(d["x"]))


@pytest.mark.parametrize("args, word", [
    (["--scene", "nowhere"], "unknown scene"),
    (["--integrator", "leapfrog"], "leapfrog"),
    (["--set", "sim.bogus=1"], "unknown key sim.bogus"),
    (["--set", "body.0.n=0"], "body.0.n"),
    (["--set", "body.0.particle_mass=-1"], "particle_mass"),
    (["--set", "body.0.stretch.k=0"], "stretch.k"),
    (["--set", "contact.epsilon=nan"], "contact.epsilon"),
    (["--set", "contact.restitution=1.2"], "restitution"),
    (["--set", "contact.friction=-0.1"], "friction"),
    (["--dt", "0"], "sim.dt"),
    (["--dt", "abc"], "--dt"),
    (["--duration", "-1"], "sim.duration"),
    (["--arch", "tpu"], "backend"),
    (["--precision", "f16"], "precision"),
    (["--set", "terrain.kind=lava"], "terrain.kind"),
    (["--set", "nonsense"], "KEY=VALUE"),
])
def test_bad_input_one_line_exit_2(cli, args, word):
    r = cli("run", *args)
    assert r.returncode == 2, (args, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and word in lines[0], r.stderr
    assert "Traceback" not in r.stderr


def test_malformed_toml(cli, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[sim\ndt = 0.001\n")
    r = cli("run", "--scene", bad)
    assert r.returncode == 2 and "malformed TOML" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_failed_run_does_not_clobber_existing_output(cli, tmp_path):
    summary = tmp_path / "keep.json"
    summary.write_text("precious")
    r = cli("run", "--set", "body.0.n=-3", "--summary", summary)
    assert r.returncode == 2
    assert summary.read_text() == "precious"


def test_unwritable_output_path(cli, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = cli("run", *SMALL, "--summary", blocker / "sub" / "s.json")
    assert r.returncode == 2 and "--summary" in r.stderr
    r = cli("run", *SMALL, "--summary", tmp_path)
    assert r.returncode == 2 and "directory" in r.stderr


def test_list(cli):
    r = cli("list")
    assert r.returncode == 0
    for word in ("plane", "tilted_plane", "sphere", "bowl", "rk4", "semi_implicit_euler", "cpu", "f64"):
        assert word in r.stdout


def test_list_options_shows_every_option_and_each_default_passes_its_own_check(cli):
    """``list --options``: every integrator's options with default, what is allowed and meaning, as its
    ``Config`` declares them; every default is a value its own check accepts, and a value given as
    TOML writes it (an integer for a real) comes back typed."""
    from taichi_soft.sim.integrators import REGISTRY

    r = cli("list", "--options")
    assert r.returncode == 0, r.stderr
    for name, cls in REGISTRY.items():
        section = r.stdout.split(f"  {name} ", 1)[1]
        for option, o in cls.Config.options().items():
            assert f"      {option} = " in section and o.doc in section, (name, option)
            assert o.check(o.default), (name, option)
            assert getattr(cls.Config.parse({option: o.default}, name), option) == o.default
    fms = REGISTRY["fast_mass_spring"].Config
    assert fms.parse({"contact_stiffness": 3000}, "fast_mass_spring").contact_stiffness == 3000.0
    assert isinstance(fms.parse({"contact_stiffness": 3000}, "fast_mass_spring").contact_stiffness, float)
    with pytest.raises(UserError, match="solver.forces: not an option of implicit_euler"):
        REGISTRY["implicit_euler"].Config.parse({"forces": "gather"}, "implicit_euler")  # no force passes


# -- scene handling in-process ------------------------------------------------------------------
def test_set_parses_toml_values_or_strings():
    assert parse_value("0.002") == 0.002
    assert parse_value("[0, 0, 0]") == [0, 0, 0]
    assert parse_value("sphere") == "sphere"
    assert parse_value("true") is True


def test_set_terrain_kind_drops_old_geometry():
    s = load_scene("plane", ["terrain.kind=sphere"])
    assert s.data["terrain"] == {"kind": "sphere", "center": [0.0, -1.0, 0.0], "radius": 3.0}


def test_set_nested_body_keys():
    s = load_scene("plane", ["body.0.stretch.k=5000", "body.0.rotation.degrees=30", "sim.gravity=[0,0,0]"])
    assert s.data["body"][0]["stretch"] == {"k": 5000.0, "damping": 60.0}
    assert s.data["body"][0]["rotation"]["degrees"] == 30.0
    assert s.data["sim"]["gravity"] == [0.0, 0.0, 0.0]


def test_override_rejects_bad_index():
    with pytest.raises(UserError):
        apply_overrides({"body": [{}]}, ["body.x.n=3"])


def test_every_shipped_scene_validates():
    from taichi_soft.sim.scene import scene_names

    names = scene_names()
    assert {"plane", "tilted_plane", "sphere", "bowl"} <= set(names)
    for name in names:
        load_scene(name)
    assert len(load_scene("three_cubes").data["body"]) >= 2


@pytest.mark.parametrize("total, fps, dt", [(1000, 30, 0.001), (100, 60, 1 / 60), (7, 30, 0.01), (5000, 24, 0.001)])
def test_frame_schedule_is_exact(total, fps, dt):
    steps = frame_steps(total, fps, dt)
    assert steps[0] == 0 and steps[-1] == total
    assert all(b > a for a, b in zip(steps, steps[1:]))
    # every frame but the last lands within half a step of k / fps
    for k, s in enumerate(steps[:-1]):
        assert abs(s * dt - k / fps) <= dt / 2 + 1e-12


def test_bench_offers_only_studies_and_no_internal_worker():
    """The speed study's configurations run as tasks (tasks.py), not through a hidden
    `bench speed-worker` command; every study `bench` accepts is listed in its help."""
    from taichi_soft.cli import build_parser

    parser = build_parser()
    bench = parser._subparsers._group_actions[0].choices["bench"]
    studies = bench._actions[1].choices
    assert all(s in bench.format_help() for s in studies) and "speed" in studies
    for bad in ("speed-worker", "nope"):
        with pytest.raises(UserError):
            parser.parse_args(["bench", bad])


def test_run_dry_run_says_what_would_be_simulated_and_the_memory(cli, tmp_path):
    """`run --dry-run` prints the run and the memory estimate, simulates and writes nothing."""
    from taichi_soft.sim.memory import estimate
    from taichi_soft.sim.scene import load_scene

    summary = tmp_path / "s.json"
    r = cli("run", "--dry-run", "--set", "body.0.n=6", "--integrator", "implicit_euler", "--dt", "0.01",
            "--duration", "2", "--summary", summary)
    assert r.returncode == 0, r.stderr
    host = estimate(load_scene("plane", ["body.0.n=6", "sim.integrator=implicit_euler"]).data, None, "f64", "cpu")["host"]
    assert "integrator implicit_euler, dt = 0.01 s, duration 2 s: 200 steps, 61 frames at 30 fps" in r.stdout
    assert "216 particles" in r.stdout and f"memory estimate {host / 1e6:.0f} MB host" in r.stdout
    assert f"would write: --summary {summary}" in r.stdout
    assert not summary.exists() and list(tmp_path.iterdir()) == []


def test_impact_at_crossing_on_a_method_without_it_is_said(cli):
    """RK4 answers impacts where its step ends: asking for the crossing rule warns, once, on stderr
    (semi-implicit Euler, which has it, says nothing)."""
    args = ("run", "--scene", "plane", "--set", "body.0.n=3", "--duration", "0.01",
            "--set", "contact.impact_at_crossing=true")
    rk4 = cli(*args, "--integrator", "rk4")
    assert rk4.returncode == 0, rk4.stderr
    said = [ln for ln in rk4.stderr.splitlines() if "impact_at_crossing" in ln]
    assert len(said) == 1 and said[0].startswith("warning:") and "rk4" in said[0], rk4.stderr
    sie = cli(*args, "--integrator", "semi_implicit_euler")
    assert sie.returncode == 0 and "impact_at_crossing" not in sie.stderr, sie.stderr
