"""The classroom demo: what each control does to the simulation (no window), the HUD wording and
pacing, and one real window under a virtual X display (without Xvfb or Vulkan they fail, see conftest.missing_tool)."""
import os
import shutil
import json
import subprocess
import sys

import numpy as np
import pytest
import taichi as ti

from taichi_soft.demo import hud
from taichi_soft.demo.controller import DemoController
from taichi_soft.demo.pacing import Pacer
from taichi_soft.sim.integrators import names

from conftest import ROOT, missing_tool

# Module fixtures hold Taichi objects across tests: one runtime for the module (conftest.py).
pytestmark = pytest.mark.taichi_shared

SMALL = ["body.0.n=3", "body.0.size=1.0", "body.0.center=[0, 1.0, 0]"]  # 27 particles: fast


@pytest.fixture(scope="module")
def ctl():
    return DemoController("plane", SMALL, integrator="semi_implicit_euler", dt=1e-3)


@pytest.fixture
def fresh(ctl):
    """The shared controller back at the scene's settings and initial state."""
    ctl.set_integrator("semi_implicit_euler")
    ctl.set_terrain("plane")
    ctl.set_dt(1e-3)
    for kind in ("stretch", "shear", "bend"):
        ctl.set_stiffness(kind, 2000.0)
    ctl.set_damping(60.0)
    ctl.set_contact(restitution=0.8, friction=0.3)
    ctl.set_particle_mass(1.0)
    ctl.set_gravity(9.8)
    ctl.set_pose(height=1.0, rotation=30.0)
    ctl.settings.paused = False
    ctl.reset()
    return ctl


class CompileCounter:
    """Counts Taichi kernel compilations (a materialize() for a key not compiled yet)."""

    def __init__(self, monkeypatch):
        self.count = 0
        original = ti.lang.kernel_impl.Kernel.materialize

        def counting(kernel, key=None, *args, **kwargs):
            if key is None or key not in kernel.compiled_kernels:
                self.count += 1
            return original(kernel, key, *args, **kwargs)

        monkeypatch.setattr(ti.lang.kernel_impl.Kernel, "materialize", counting)


def positions(ctl):
    return ctl.sim.state.x.to_numpy()


def test_every_registered_integrator_switches_live_from_the_current_state(fresh):
    fresh.step(50)
    for name in names():
        before, t = positions(fresh), fresh.sim.time
        fresh.set_integrator(name)
        assert fresh.sim.integrator_name == name == fresh.settings.integrator
        np.testing.assert_array_equal(positions(fresh), before)  # switching keeps the state
        assert fresh.step(5) == 5, fresh.message
        assert fresh.sim.time == pytest.approx(t + 5e-3)
        assert not np.array_equal(positions(fresh), before)


def test_terrain_switch_rebuilds_resets_and_keeps_the_other_settings(fresh):
    fresh.set_integrator("midpoint")
    fresh.set_dt(5e-4)
    fresh.set_stiffness("shear", 3000.0)
    fresh.set_contact(friction=0.6)
    fresh.set_gravity(5.0)
    fresh.step(20)
    old_sim = fresh.sim
    fresh.set_terrain("sphere")
    sim = fresh.sim
    assert sim is not old_sim and sim.terrain.kind == "sphere" and fresh.settings.terrain == "sphere"
    assert sim.time == 0.0 and sim.integrator_name == "midpoint" and sim.dt == 5e-4
    assert sim.model.group_k.to_numpy()[1] == 3000.0
    assert sim.terrain.friction[None] == pytest.approx(0.6)
    np.testing.assert_allclose(sim.model.gravity.to_numpy(), [0.0, -5.0, 0.0])
    assert fresh.step(10) == 10


def test_terrains_are_built_once_and_a_return_carries_the_settings_made_elsewhere(fresh, monkeypatch):
    plane = fresh.sim
    fresh.set_terrain("sphere")
    sphere = fresh.sim
    fresh.set_integrator("rk4")  # built on the sphere's simulation only ...
    fresh.step(1)
    fresh.set_terrain("plane")
    assert fresh.sim is plane and fresh.sim.integrator_name == "rk4"  # ... and on the plane's on return
    fresh.step(1)
    compiles = CompileCounter(monkeypatch)
    for _ in range(40):  # a class flicking between terrains: nothing new is built or compiled
        fresh.set_terrain("sphere")
        assert fresh.sim is sphere and fresh.step(3) == 3
        fresh.set_terrain("plane")
        assert fresh.sim is plane and fresh.step(3) == 3
    assert compiles.count == 0
    fresh.set_dt(5e-4)  # changed on the plane ...
    fresh.set_stiffness("bend", 1500.0)
    fresh.set_contact(restitution=0.5)
    fresh.set_particle_mass(2.0)
    fresh.set_gravity(4.0)
    fresh.set_terrain("sphere")  # ... hold on the sphere's kept simulation, which starts again
    sim = fresh.sim
    assert sim is sphere and sim.time == 0.0 and sim.integrator_name == "rk4" and sim.dt == 5e-4
    assert sim.model.group_k.to_numpy()[2] == 1500.0 and sim.terrain.restitution[None] == pytest.approx(0.5)
    assert (sim.model.mass_np == 2.0).all()
    np.testing.assert_allclose(sim.model.gravity.to_numpy(), [0.0, -4.0, 0.0])
    np.testing.assert_allclose(positions(fresh), fresh._initial_pose()[0])


@pytest.mark.parametrize("control", ["stiffness", "damping", "dt", "gravity", "mass", "restitution", "friction"])
def test_live_controls_change_the_next_step_without_a_recompile(fresh, monkeypatch, control):
    fresh.set_pose(height=-0.2)  # lowest corner 0.1 m above the plane (y = -1): lands within 0.3 s
    # That landing (1.4 m/s at most) is barely above the 1 m/s bounce threshold: bounce every
    # approach, so that restitution acts on this short drop.
    fresh.sim.terrain.set_contact(bounce_threshold=0.0)
    fresh.reset()
    fresh.step(300)
    reference = positions(fresh)
    fresh.reset()
    counter = CompileCounter(monkeypatch)
    {"stiffness": lambda: fresh.set_stiffness("stretch", 8000.0), "damping": lambda: fresh.set_damping(5.0),
     "dt": lambda: fresh.set_dt(1.1e-3), "gravity": lambda: fresh.set_gravity(20.0),
     "mass": lambda: fresh.set_particle_mass(3.0), "restitution": lambda: fresh.set_contact(restitution=0.0),
     "friction": lambda: fresh.set_contact(friction=1.2)}[control]()
    fresh.step(300)
    assert counter.count == 0  # no kernel compiled (a recompile alone takes about a second)
    assert np.abs(positions(fresh) - reference).max() > 1e-9


def test_reset_restores_the_initial_state_with_the_new_pose(fresh):
    x0 = positions(fresh).copy()
    fresh.step(200)
    fresh.reset()
    np.testing.assert_array_equal(positions(fresh), x0)
    assert fresh.sim.time == 0.0 and fresh.message is None
    fresh.set_pose(height=3.0, rotation=30.0)  # height only: +2 m
    fresh.step(10)
    fresh.reset()
    np.testing.assert_allclose(positions(fresh), x0 + [0.0, 2.0, 0.0])
    fresh.set_pose(height=1.0, rotation=0.0)
    fresh.reset()
    x = positions(fresh)
    center = x.mean(axis=0)
    assert np.allclose(np.sort(np.abs(x - center)[:, 1])[-1], 0.5)  # level again: edges 0.5 m from centre


def test_divergence_pauses_with_a_message_and_reset_recovers(fresh):
    fresh.set_integrator("explicit_euler")
    fresh.set_stiffness("stretch", 1e6)
    fresh.set_dt(0.01)
    fresh.step(500)
    msg = fresh.message
    assert msg and msg.startswith("diverged at t = ") and "explicit_euler" in msg and "dt = 0.01 s" in msg
    hint = fresh.sim.suggest_dt()  # below explicit Euler's linear stability limit with k = 1e6
    assert f"try dt <= {hint:g}" in msg and hint < 1e-4
    assert fresh.settings.paused and fresh.step(10) == 0
    assert fresh.last_measures is not None and np.isfinite(fresh.last_measures["total_energy"])
    fresh.set_dt(1e-4)
    fresh.reset()
    assert fresh.message is None and fresh.step(10) == 10


def test_controls_reject_unknown_names(fresh):
    from taichi_soft.errors import UserError

    with pytest.raises(UserError):
        fresh.set_integrator("leapfrog")
    with pytest.raises(UserError):
        fresh.set_terrain("volcano")
    assert fresh.sim.integrator_name == "semi_implicit_euler" and fresh.sim.terrain.kind == "plane"


def test_hud_lines_say_time_pace_energy_and_solver_iterations(fresh):
    fresh.step(10)
    fresh.sample()
    pacer = Pacer()
    lines = hud.status_lines(fresh, pacer, {"steps": 10, "newton_iterations_per_step": 2.0,
                                            "cg_iterations_per_step": 14.5})
    assert lines[0].startswith("t =") and "semi_implicit_euler" in lines[0] and "dt = 0.001 s" in lines[0]
    assert lines[2].startswith("E - E(0) = ") and "kin" in lines[2] and "spring" in lines[2] and "grav" in lines[2]
    assert lines[3] == "iterations per step: Newton 2.0, CG 14.5"
    assert hud.pace_text(True, 1.0, 0.0, 0.0, False) == "PAUSED"
    assert "2.5x slower" in hud.pace_text(False, 1.0, 0.4, 400.0, True)
    plot = hud.energy_plot(fresh.history, (0, 0, 100, 50))
    assert [k for k, _ in plot] == list(hud.ENERGY_KEYS)
    assert all(p[:, 1].min() >= 0 and p[:, 1].max() <= 50 for _, p in plot)


def test_pause_keeps_the_plot_history_and_restart_pauses(fresh):
    fresh.step(20)
    fresh.sample()
    fresh.toggle_pause()
    kept = list(fresh.history.t)
    for _ in range(300):  # a paused window samples every frame: nothing new to plot
        fresh.sample()
    assert fresh.history.t == kept and len(kept) >= 2
    fresh.step(1)  # a single step while paused adds its sample
    fresh.sample()
    assert fresh.history.t == kept + [pytest.approx(kept[-1] + 1e-3)]
    fresh.settings.paused = False
    fresh.restart()
    assert fresh.settings.paused and fresh.sim.time == 0.0 and fresh.history.t == [0.0]


def test_ladder_steps_in_physical_1_2_5_values():
    from taichi_soft.demo.panel import ladder

    assert [ladder(1e-3, +1), ladder(1e-3, -1), ladder(2e-3, +1), ladder(5e-4, -1)] == [2e-3, 5e-4, 5e-3, 2e-4]
    assert [ladder(2000.0, +1), ladder(2000.0, -1), ladder(3000.0, +1), ladder(3000.0, -1)] == [5e3, 1e3, 5e3, 2e3]
    k, clicks = 2000.0, 0
    while k < 1e5:  # experiment 1 in docs/teaching.md: 2000 -> 1e5 N/m
        k, clicks = ladder(k, +1), clicks + 1
    assert k == 1e5 and clicks == 5


def test_screenshot_names_never_overwrite(tmp_path):
    from taichi_soft.demo.capture import default_path

    first = default_path("shot", "plane", ".png", folder=str(tmp_path))
    first.write_bytes(b"1")
    second = default_path("shot", "plane", ".png", folder=str(tmp_path))
    assert second != first and not second.exists()


def test_pacer_takes_real_time_steps_and_reports_falling_behind():
    now = [0.0]
    pacer = Pacer(budget=0.05, clock=lambda: now[0])
    assert pacer.plan(1e-3) == 0  # first frame: no time has passed
    steps = []
    for _ in range(60):  # one second at 60 frames/s, each step costing 10 us
        now[0] += 1 / 60
        n = pacer.plan(1e-3)
        steps.append(n)
        pacer.record(n, n * 1e-5, 1e-3)
    assert sum(steps) in (999, 1000, 1001) and set(steps) <= {16, 17}
    assert pacer.realtime_factor == pytest.approx(1.0, abs=0.03) and not pacer.limited
    for _ in range(60):  # now each step costs 1 ms: only 50 fit in a frame's budget
        now[0] += 1 / 60
        n = pacer.plan(1e-4)
        pacer.record(n, n * 1e-3, 1e-4)
    assert pacer.limited and pacer.realtime_factor < 0.4


# -- the real window ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def xvfb():
    """A virtual X display on a free number (Xvfb picks it: -displayfd); yields DISPLAY."""
    if shutil.which("Xvfb") is None:
        missing_tool("Xvfb is not installed (apt-get install xvfb)")
    read, write = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                            pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    with os.fdopen(read) as f:
        number = f.readline().strip()
    if not number:
        proc.kill()
        missing_tool("Xvfb did not start")
    yield f":{number}"
    proc.terminate()
    proc.wait(timeout=10)


def test_demo_window_draws_the_scene_and_hud(xvfb, tmp_path):
    shot = tmp_path / "shot.png"
    env = dict(os.environ, DISPLAY=xvfb, PYTHONUNBUFFERED="1")
    # cwd = tmp_path: ImGui writes its imgui.ini into the working directory.
    proc = subprocess.run([sys.executable, str(ROOT / "main.py"), "demo", "--scene", "plane", "--integrator", "rk4",
                           "--set", "body.0.n=5", "--resolution", "640x400", "--frames", "8", "--screenshot", str(shot)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    if proc.returncode == 2 and "Vulkan" in proc.stderr:
        missing_tool(f"no Vulkan device: {proc.stderr.strip()}")
    assert proc.returncode == 0, proc.stderr
    from PIL import Image

    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert img.shape == (400, 640, 3)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    scene = np.s_[:, : int(0.7 * 640)]
    orange = (r > g + 50) & (g > b + 30)  # the cube (BODY_COLORS[0], shaded)
    assert orange[scene].sum() > 300
    assert ((abs(r - 219) < 12) & (abs(b - 237) < 12))[scene].sum() > 1000  # sky (BACKGROUND)
    panel = img[40:380, int(0.72 * 640):]  # ImGui controls: dark, with blue sliders
    assert panel.mean() < 90 and ((b > r + 60) & (b > 100))[40:380, int(0.72 * 640):].sum() > 200
    hud_text = img[5:60, 5:300]  # large white HUD text with a dark outline
    assert (hud_text.min(axis=2) > 235).sum() > 300 and (hud_text.max(axis=2) < 40).sum() > 300


def test_every_advertised_control_works_through_real_x_input(xvfb, tmp_path):
    """Keys pressed and buttons clicked through the X server (XTest), as a teacher would: every
    key the HUD advertises, the Screenshot, integrator buttons; the demo keeps running after each
    (``tests.x11.scripted`` checks what each did), screenshots show the scene, a pause keeps
    the plot's history, and Esc closes the window."""
    env = dict(os.environ, DISPLAY=xvfb, PYTHONUNBUFFERED="1", PYTHONPATH=str(ROOT))
    # 700 px: the panel's left column, one button per integrator, fits (at 640 its last rows are cut off)
    proc = subprocess.run([sys.executable, "-m", "tests.x11.scripted", "--set", "body.0.n=3",
                           "--resolution", "1024x700"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=400)
    if "Vulkan" in proc.stderr and proc.returncode != 0 and "checks" not in proc.stdout:
        missing_tool(f"no Vulkan device: {proc.stderr.strip().splitlines()[-1]}")
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    assert lines, (proc.returncode, proc.stdout[-2000:], proc.stderr[-2000:])
    checks = json.loads(lines[-1])["checks"]
    assert {k: v for k, v in checks.items() if v != "ok"} == {}
    assert len(checks) == 15 and proc.returncode == 0, (checks, proc.stderr[-2000:])
    assert len(list((tmp_path / "out").glob("*.png"))) == 2 and len(list((tmp_path / "out").glob("*.mp4"))) == 1


def test_demo_without_a_display_says_so_in_one_line(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.run([sys.executable, str(ROOT / "main.py"), "demo"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "display" in lines[0] and "run --video" in lines[0], proc.stderr


# -- the hand: grab, pins, poke, recorded inputs (controller level; the window's mouse below) -------
def _top_centre(ctl) -> int:
    x = positions(ctl)
    return int(np.argmin(np.linalg.norm(x - [x[:, 0].mean(), x[:, 1].max(), x[:, 2].mean()], axis=1)))


@pytest.mark.parametrize("name, dt", [("semi_implicit_euler", 1e-3), ("explicit_euler", 1e-3), ("midpoint", 1e-3),
                                      ("rk4", 1e-3), ("implicit_euler", 1 / 30), ("fast_mass_spring", 1 / 30)])
def test_a_grabbed_body_hangs_where_the_spring_carries_its_weight(fresh, name, dt):
    """Lift the level cube by its top-centre particle (no swing): at rest the grab spring carries
    the whole weight, so the particle hangs M g / k below its target, whatever the integrator."""
    fresh.set_pose(height=1.0, rotation=0.0)
    fresh.set_integrator(name)
    fresh.set_dt(dt)
    fresh.reset()
    i = _top_centre(fresh)
    target = positions(fresh)[i] + [0.0, 1.0, 0.0]
    fresh.grab_particle(i, target)
    fresh.step(int(round(8.0 / dt)))
    assert fresh.message is None, fresh.message
    sag = target[1] - positions(fresh)[i, 1]
    weight = fresh.sim.model.mass_np.sum() * 9.8
    assert sag == pytest.approx(weight / fresh.settings.grab_stiffness, rel=0.01)
    np.testing.assert_allclose(positions(fresh)[i, [0, 2]], target[[0, 2]], atol=1e-3)
    fresh.release()
    fresh.step(int(round(1.0 / dt)))
    assert positions(fresh)[i, 1] < target[1] - sag - 1.0  # let go: it falls


@pytest.mark.parametrize("name, dt", [("semi_implicit_euler", 1e-3), ("explicit_euler", 1e-3), ("midpoint", 1e-3),
                                      ("rk4", 1e-3), ("implicit_euler", 1 / 30), ("fast_mass_spring", 1 / 30)])
def test_every_integrator_survives_a_hard_yank(fresh, name, dt):
    """A corner yanked 3 m up by a 1e5 N/m spring (300 kN at first): no divergence, and the corner
    ends up at the target (the body's 265 N weight stretches that spring by 3 mm)."""
    fresh.set_integrator(name)
    fresh.set_dt(dt)
    fresh.reset()
    fresh.step(int(round(1.0 / dt)))  # landed
    fresh.set_grab_stiffness(1e5)
    x = positions(fresh)
    i = int(np.argmax(x[:, 1]))
    target = x[i] + [0.0, 3.0, 0.0]
    fresh.grab_particle(i, target)
    fresh.step(int(round(1.0 / dt)))
    assert fresh.message is None, fresh.message
    assert np.isfinite(positions(fresh)).all()
    assert np.linalg.norm(positions(fresh)[i] - target) < 0.15
    fresh.set_grab_stiffness(1000.0)


def test_fast_mass_spring_carries_a_stiff_grab_in_its_factor(fresh):
    """A 1e6 N/m grab at 1/30 s adds 1.1e3 kg to one diagonal entry of the step's matrix, far above
    the prefactored M + L's: fast_mass_spring folds it into its factor (Sherman-Morrison), so each
    step of a 1 m yank of this 1 m cube ends near the tolerance (the cap stops the local/global
    iteration's linear convergence at 0.1-0.5 m/s^2), at the state Newton's steps reach."""
    ends = {}
    for name in ("fast_mass_spring", "implicit_euler"):
        fresh.set_integrator(name)
        fresh.set_dt(1 / 30)
        fresh.set_pose(height=3.0, rotation=30.0)
        fresh.reset()
        fresh.set_grab_stiffness(1e6)
        i = _top_centre(fresh)
        fresh.grab_particle(i, positions(fresh)[i] + [0.0, 1.0, 0.0])
        integ = fresh.sim.integrator
        integ.stats()  # start the averages here
        for _ in range(4):  # in the air: nothing touches the terrain
            fresh.step(1)
            st = integ.stats()
            if name == "fast_mass_spring":  # (without the grab in the factor: 80-1.8e5 m/s^2)
                assert st["final_residual_m_s2"] < 10 * integ.options.tol
        ends[name] = positions(fresh)
        fresh.release()
        fresh.set_grab_stiffness(1000.0)
    # both stop within the tolerance of the same minimiser: 0.1 m/s^2 x h^2 is ~1e-4 m per step
    assert np.abs(ends["fast_mass_spring"] - ends["implicit_euler"]).max() < 2e-3


def test_explicit_euler_blows_up_on_a_yank_at_a_large_step_and_reset_recovers(fresh):
    fresh.set_integrator("explicit_euler")
    fresh.set_dt(2e-3)
    fresh.step(100)
    assert fresh.message is None  # stable without the yank
    fresh.set_grab_stiffness(1e6)  # dt sqrt(k / m) = 2: past explicit Euler's limit
    i = _top_centre(fresh)
    fresh.grab_particle(i, positions(fresh)[i] + [0.0, 2.0, 0.0])
    fresh.step(500)
    assert fresh.message and fresh.message.startswith("diverged") and "R resets" in fresh.message
    fresh.set_grab_stiffness(1000.0)
    fresh.reset()
    assert fresh.grab.held is None and fresh.message is None and fresh.step(10) == 10


@pytest.mark.parametrize("name, dt", [("semi_implicit_euler", 1e-3), ("rk4", 1e-3), ("implicit_euler", 1 / 30),
                                      ("fast_mass_spring", 1 / 30)])
def test_pinned_corners_hold_the_body_and_survive_switches(fresh, name, dt):
    fresh.set_integrator(name)
    fresh.set_dt(dt)
    fresh.set_pose(height=1.0, rotation=0.0)
    fresh.reset()
    x0 = positions(fresh)
    top = np.flatnonzero(np.isclose(x0[:, 1], x0[:, 1].max()))
    edge = top[np.isclose(x0[top, 0], x0[top, 0].min())]  # the top face's edge at the lowest x
    a, b = int(edge[np.argmin(x0[edge, 2])]), int(edge[np.argmax(x0[edge, 2])])  # its two corners
    fresh.toggle_pin(a)
    fresh.toggle_pin(b)
    assert fresh.pins == {a, b} and fresh.sim.model.mass_np[[a, b]].tolist() == [0.0, 0.0]
    free = np.setdiff1d(np.arange(len(x0)), [a, b])
    lowest = np.inf
    for _ in range(20):  # 2 s: the body swings down about the pinned edge and hangs from it
        fresh.step(int(round(0.1 / dt)))
        x = positions(fresh)
        np.testing.assert_array_equal(x[[a, b]], x0[[a, b]])  # pinned: not moved at all
        assert x[free, 1].max() < x0[a, 1] + 0.05 and x[free, 1].min() > -1.0  # below its pins, off the floor
        lowest = min(lowest, x[free, 1].mean())
    assert fresh.message is None, fresh.message
    # Hanging at rest, the centre of mass is 0.71 m (half the face diagonal) below the edge: 0.21 m
    # below where it started level with it.
    assert lowest < x0[free, 1].mean() - 0.15 and x[free, 1].mean() < x0[free, 1].mean() - 0.05
    other = "rk4" if name != "rk4" else "midpoint"
    fresh.set_integrator(other)  # pins survive an integrator switch ...
    fresh.step(20)
    np.testing.assert_array_equal(positions(fresh)[[a, b]], x0[[a, b]])
    fresh.set_terrain("sphere")  # ... and a terrain switch (the body starts again, pinned)
    assert fresh.pins == {a, b} and fresh.sim.model.mass_np[[a, b]].tolist() == [0.0, 0.0]
    fresh.set_terrain("plane")
    fresh.set_integrator(name)
    fresh.clear_pins()
    assert not fresh.pins and (fresh.sim.model.mass_np == fresh.settings.particle_mass).all()
    fresh.step(int(round(0.5 / dt)))
    assert positions(fresh)[[a, b], 1].max() < x0[[a, b], 1].min() - 0.5  # unpinned: falls
    fresh.toggle_pin(a)
    fresh.reset()  # reset clears pins
    assert not fresh.pins and (fresh.sim.model.mass_np == fresh.settings.particle_mass).all()


def test_a_poke_adds_the_slider_speed_along_the_ray(fresh):
    fresh.set_poke_speed(4.0)
    v0 = fresh.sim.state.v.to_numpy()[5]
    fresh.poke(5, [0.0, 0.0, -2.0])
    np.testing.assert_allclose(fresh.sim.state.v.to_numpy()[5] - v0, [0.0, 0.0, -4.0])
    fresh.set_poke_speed(3.0)


def test_recorded_inputs_replay_to_the_same_state(fresh):
    from taichi_soft.demo.session import SessionRecorder

    class Camera:
        position, lookat, up, fov = (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0

    class App:  # what SessionRecorder reads of the window
        cam_spec, draw = Camera(), {"surface": True}

    rec = SessionRecorder("unused.json", {})
    fresh.recorder = rec
    try:
        fresh.set_grab_stiffness(5000.0)
        fresh.grab_particle(3, (0.1, 2.0, 0.3))
        fresh.step(40)
        rec.end_frame(App)
        fresh.drag(np.array([0.5, 2.5, 0.0]))
        fresh.step(37)
        fresh.release()
        fresh.toggle_pin(7)
        fresh.poke(11, (1.0, 0.0, 0.0))
        fresh.set_contact(friction=0.5)
        fresh.step(50)
        rec.end_frame(App)
    finally:
        fresh.recorder = None
    live = positions(fresh)
    names = [op[0] for f in rec.frames for op in f["ops"]]
    assert names == ["set_grab_stiffness", "grab_particle", "step", "drag", "step", "release", "toggle_pin", "poke",
                     "set_contact", "step"]  # outermost inputs only (set_contact's own work is not logged)
    fresh.set_grab_stiffness(1000.0)
    fresh.set_contact(friction=0.3)
    fresh.reset()
    for frame in json.loads(json.dumps(rec.frames)):  # through JSON, as a session file
        for name, args, kwargs in frame["ops"]:
            getattr(fresh, name)(*args, **kwargs)
    np.testing.assert_array_equal(positions(fresh), live)
    fresh.set_grab_stiffness(1000.0)
    fresh.set_contact(friction=0.3)


def pick_surface(points: np.ndarray, triangles: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> int | None:
    """Reference for ``surface_pick.SurfacePicker`` in numpy: the nearest ``triangles`` [m, 3]
    (particle indices) crossed in front of the origin (Moller-Trumbore), and of that triangle the
    corner nearest the hit point. None if the ray crosses no triangle."""
    a, b, c = points[triangles[:, 0]], points[triangles[:, 1]], points[triangles[:, 2]]
    e1, e2 = b - a, c - a
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ direction) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    if not hit.any():
        return None
    k = np.flatnonzero(hit)[np.argmin(t[hit])]
    corners = triangles[k]
    return int(corners[np.argmin(np.linalg.norm(points[corners] - (origin + t[k] * direction), axis=1))])


def test_picking_finds_the_particle_under_the_cursor(make_sim):
    from taichi_soft.demo.picking import pick, plane_point, view_ray
    from taichi_soft.demo.surface_pick import SurfacePicker
    from taichi_soft.sim.lattice import surface_triangles
    from taichi_soft.render.camera import CameraSpec, project

    n = 3
    sim = make_sim("plane", ["body.0.n=3", "body.0.size=1.0", "body.0.center=[0, 0, 0]", "body.0.rotation.degrees=0"])
    g = sim.state.x.to_numpy().astype(np.float64)
    picker = SurfacePicker(sim.model)
    cam = CameraSpec((3.0, 2.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0)
    w, h = 800, 600
    tri = surface_triangles(n)
    eye = np.asarray(cam.position)
    for i in range(len(g)):
        col, row = project(g[i][None], cam, w, h)[0]
        o, d = view_ray(cam, col / w, 1 - row / h, w / h)
        assert np.linalg.norm(np.cross(g[i] - o, d)) < 1e-9  # the ray passes through the point
        if np.linalg.norm(g[i] - eye) <= np.linalg.norm(g - eye, axis=1).min() + 1e-9:
            assert pick_surface(g, tri, o, d) == i  # the corner nearest the camera is picked
            assert picker.pick(sim.state.x, o, d)[0] == i
    # The device picker against numpy on rays through each triangle's centre (a ray through a
    # particle or along an edge is a tie that rounding may break either way), from two cameras.
    for eye in (eye, np.array([-2.0, 3.0, -3.0])):
        for k in range(len(tri)):
            d = g[tri[k]].mean(axis=0) - eye
            d /= np.linalg.norm(d)
            on_device = picker.pick(sim.state.x, eye, d)
            assert on_device is not None and on_device[0] == pick_surface(g, tri, eye, d)
            np.testing.assert_allclose(on_device[1], g[on_device[0]], atol=1e-12)
    assert picker.pick(sim.state.x, eye, -np.asarray(eye) / np.linalg.norm(eye) + [0.0, 0.8, 0.0]) is None  # sky
    # a ray just outside the silhouette picks the particle nearest it; a ray past the body: nothing
    o, d = view_ray(cam, 0.5, 0.5, w / h)
    assert pick(g, o, d + [0.0, 0.3, 0.0], 0.1) is None
    p = plane_point(o, d, np.zeros(3), -d)
    np.testing.assert_allclose(p, [0.0, 0.0, 0.0], atol=1e-12)


def test_the_mouse_grabs_pins_and_pokes_and_a_recorded_session_replays(xvfb, tmp_path):
    """Through the X server (``scripted --hands``): Shift+click two top corners, the body hangs
    from them for 2 s with the pins fixed; X clears them and it falls; R clears a pin; a top
    corner dragged 150 px up for 1 s rises and the body follows, released it falls back; a click
    pokes along the view ray; explicit Euler at dt = 2 ms yanked by a 1e6 N/m spring diverges,
    says so, and R recovers. The session is recorded, then ``demo --replay`` renders it without a
    display and ends in exactly the live session's state."""
    env = dict(os.environ, DISPLAY=xvfb, PYTHONUNBUFFERED="1", PYTHONPATH=str(ROOT))
    session = tmp_path / "session.json"
    proc = subprocess.run([sys.executable, "-m", "tests.x11.scripted", "--hands", "--yank",
                           "explicit_euler:0.002:1e6", "--record", str(session), "--resolution", "1024x640",
                           "--set", "body.0.n=3", "--set", "body.0.size=1.0", "--set", "body.0.center=[0, 0.5, 0]",
                           "--set", "body.0.rotation.degrees=0", "--set", "contact.restitution=0"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    if "Vulkan" in proc.stderr and proc.returncode != 0 and "checks" not in proc.stdout:
        missing_tool(f"no Vulkan device: {proc.stderr.strip().splitlines()[-1]}")
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    assert lines, (proc.returncode, proc.stdout[-2000:], proc.stderr[-2000:])
    report = json.loads(lines[-1])
    assert {k: v for k, v in report["checks"].items() if v != "ok"} == {}
    assert len(report["checks"]) == 7 and report["actions"]["yank"] == "diverged, reset" and proc.returncode == 0
    live = json.loads(session.read_text())
    assert live["final"]["steps"] == report["final"]["steps"] > 0
    ops = {op[0] for frame in live["frames"] for op in frame["ops"]}
    assert {"toggle_pin", "clear_pins", "grab_particle", "drag", "release", "poke", "restart"} <= ops

    video = tmp_path / "replay.mp4"
    env.pop("DISPLAY")  # headless
    proc = subprocess.run([sys.executable, str(ROOT / "main.py"), "demo", "--replay", str(session), "--video",
                           str(video)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "final state identical to the recorded session's" in proc.stdout
    assert video.stat().st_size > 10_000


def test_replay_refuses_what_it_cannot_play(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "something else"}')
    for args, says in ((["--replay", str(tmp_path / "missing.json")], "no such file"),
                       (["--replay", str(bad)], "not a taichi-soft demo session"),
                       (["--replay", str(bad), "--record", str(tmp_path / "s.json")], "exclude each other"),
                       (["--record", str(tmp_path / "s.txt")], "expected a file ending in .json"),
                       (["--video", str(tmp_path / "v.mp4")], "--video goes with --replay")):
        proc = subprocess.run([sys.executable, str(ROOT / "main.py"), "demo", *args], cwd=tmp_path,
                              capture_output=True, text=True, timeout=120)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and says in lines[0], (args, proc.stderr)


def test_duration_stops_the_demo_there_and_r_restarts(fresh):
    """`demo --duration` was accepted and ignored; the simulation now stops at it."""
    fresh.settings.duration = 0.05
    try:
        assert fresh.step(1000) == 50
        assert fresh.sim.time == pytest.approx(0.05) and fresh.message is None
        assert fresh.step(10) == 0 and fresh.sim.time == pytest.approx(0.05)
        assert fresh.message.startswith("stopped at t = 0.050 s, the end of --duration 0.05 s") and fresh.settings.paused
        fresh.reset()
        assert fresh.message is None and fresh.step(20) == 20
    finally:
        fresh.settings.duration = None


def test_demo_passes_its_duration_to_the_window(monkeypatch):
    from taichi_soft import cli
    from taichi_soft.commands import common
    from taichi_soft.demo import app

    seen = {}
    monkeypatch.setattr(common, "start_taichi", lambda args: None)
    monkeypatch.setattr(app, "run_demo", lambda *a, **kw: seen.update(kw))
    assert cli.main(["demo", "--set", "body.0.n=3", "--duration", "0.25"]) == 0
    assert seen["duration"] == 0.25
    assert cli.main(["demo", "--set", "body.0.n=3"]) == 0
    assert seen["duration"] is None  # no --duration: the demo runs on (the scene's duration is for `run`)


def test_energies_are_shown_as_changes_since_the_start(fresh):
    """The HUD's energies were totals against y = 0 (kJ of gravity energy that hid the
    changes); they are now changes since t = 0, in the text and in the plot (legend says so)."""
    pacer = Pacer()
    assert hud.status_lines(fresh, pacer)[2] == "E - E(0) = 0 J = kin 0 + spring 0 + grav 0"
    start = dict(fresh.last_measures)
    fresh.step(100)
    m = fresh.sample()
    line = hud.status_lines(fresh, pacer)[2]
    d = {k: m[k] - start[k] for k in hud.ENERGY_KEYS}
    assert d["gravity_energy"] < -1.0 and d["kinetic_energy"] > 1.0  # falling
    assert line == (f"E - E(0) = {hud.energy_text(d['total_energy'])} J = kin {hud.energy_text(d['kinetic_energy'])} "
                    f"+ spring {hud.energy_text(d['spring_energy'])} + grav {hud.energy_text(d['gravity_energy'])}")
    plot = dict(hud.energy_plot(fresh.history, (0, 0, 100, 50)))
    first_y = {k: p[0, 1] for k, p in plot.items()}
    assert len(set(np.round(list(first_y.values()), 9))) == 1  # every series starts at the same zero line
    assert hud.PLOT_TITLE == "change since t = 0:"
