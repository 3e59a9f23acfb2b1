"""The examples in examples/ run as a user runs them (a fresh process, from the repository) and
give the physics they claim."""
import re
import subprocess
import sys

import pytest

from taichi_soft.paths import ROOT

EXAMPLES = ROOT / "examples"


def _run(name: str) -> str:
    done = subprocess.run([sys.executable, str(EXAMPLES / name)], capture_output=True, text=True,
                          timeout=600, cwd=EXAMPLES)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_drop_cube_comes_to_rest_on_the_plane():
    """A 2 m cube on the plane y = 0 rests with its centre 1 m up (its springs barely sag)."""
    out = _run("drop_cube.py")
    centres = [float(c) for c in re.findall(r"centre y = ([-+0-9.]+) m", out)]
    assert centres[0] == 2.0
    assert abs(centres[-1] - 1.0) < 0.03, out


def test_rk4_is_closer_to_the_reference_than_semi_implicit_euler():
    """At the same step a fourth-order method sits far closer to the tiny-step reference."""
    out = _run("compare_integrators.py")
    errors = dict(re.findall(r"^(\w+)\s.*error ([0-9.e+-]+) m$", out, re.M))
    assert set(errors) == {"semi_implicit_euler", "rk4"}, out
    assert float(errors["rk4"]) < 0.2 * float(errors["semi_implicit_euler"]), out
    assert float(errors["semi_implicit_euler"]) < 0.2, out


def test_from_parts_falls_as_free_fall_says():
    """No terrain, springs at rest: the centre falls g t^2 / 2, which RK4 integrates exactly."""
    out = _run("from_parts.py")
    t, fell, _ = (float(v) for v in re.search(r"t = ([0-9.]+) s\s+centre fell ([0-9.]+) m\s+\(g t\^2 / 2 = ([0-9.]+)",
                                                 out).groups())
    assert t == 0.5 and abs(fell - 0.5 * 9.8 * t ** 2) < 1e-8, out


def test_from_parts_refuses_what_a_scene_file_refuses():
    """The parts are validated as a TOML scene: the same message for the same bad key, before any work."""
    from taichi_soft.errors import UserError
    from taichi_soft.sim import BodySpec, Simulation, scene_from_dict

    for parts, table, says in (
            ({"bodies": [{"n": 1}]}, {"body": [{"n": 1}]}, "body.0.n = 1: must be an integer from 2 to"),
            ({"bodies": [BodySpec()], "restitution": 1.5}, {"contact": {"restitution": 1.5}}, "contact.restitution"),
            ({"bodies": [BodySpec()], "terrain": "lava"}, {"terrain": {"kind": "lava"}}, "terrain.kind = 'lava'"),
            ({"bodies": [BodySpec()], "dt": -1.0}, {"sim": {"dt": -1.0}}, "sim.dt")):
        with pytest.raises(UserError) as from_parts:
            Simulation.from_parts(**parts)
        with pytest.raises(UserError) as from_file:
            scene_from_dict({"body": [{}], **table})
        assert says in str(from_parts.value)
        assert str(from_parts.value).split(": ", 1)[1] == str(from_file.value).split(": ", 1)[1]


def test_a_custom_integrator_runs_and_follows_its_own_order():
    """A registered drift-kick-drift Verlet is exact for a constant acceleration (the parabola to
    round-off); symplectic Euler at the same step is off by g h t / 2."""
    out = _run("custom_integrator.py")
    rows = {name: (float(t), float(err), float(offset)) for name, t, err, offset in re.findall(
        r"^(\w+)\s+t = ([0-9.]+) s\s+distance from the parabola ([0-9.e+-]+) m\s+\(g h t / 2 = ([0-9.e+-]+) m\)",
        out, re.M)}
    assert set(rows) == {"position_verlet", "semi_implicit_euler"}, out
    t, err, _ = rows["position_verlet"]
    assert t == 0.5 and err < 1e-12, out
    t, err, _ = rows["semi_implicit_euler"]
    assert err == pytest.approx(9.8 * 1e-3 * t / 2, rel=1e-6), out


def test_mesh_body_comes_to_rest_above_the_plane():
    """The torus lands flat and rests: on the plane y = 0 within the contact layer (1 cm), its
    half height held up to a small sag, every particle still."""
    out = _run("mesh_body.py")
    half = float(re.search(r"half height ([0-9.]+) m", out).group(1))
    rows = [(float(t), float(low), float(centre), float(speed)) for t, low, centre, speed in re.findall(
        r"t = ([0-9.]+) s\s+lowest point y = ([-+0-9.]+) m\s+centre y = ([-+0-9.]+) m\s+fastest particle ([0-9.]+)",
        out)]
    t, low, centre, speed = rows[-1]
    assert t == 2.0 and rows[0][2] == 1.0, out
    assert 0.0 <= low <= 0.011, out
    assert 0.95 * half < centre - low <= half, out
    assert speed < 1e-3, out


def test_every_example_is_tested():
    tested = {"drop_cube.py", "compare_integrators.py", "from_parts.py", "custom_integrator.py", "mesh_body.py"}
    assert {p.name for p in EXAMPLES.glob("*.py")} == tested


def test_the_readme_python_example_is_drop_cube():
    """The README shows examples/drop_cube.py's code as it runs here (less the lint markers)."""
    readme = (ROOT / "README.md").read_text()
    shown = readme.split("```python\n", 1)[1].split("```", 1)[0]
    code = (EXAMPLES / "drop_cube.py").read_text().replace("  # noqa: E402", "")
    assert shown.strip() and shown.strip() in code
