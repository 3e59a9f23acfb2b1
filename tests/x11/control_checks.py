"""The checks of every control the HUD advertises, through real X input (``scripted``): each
key pressed and panel buttons clicked, what it did to the demo's state checked after each; and
the closing check that Esc quits.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from taichi_soft.demo.panel import DRAW_KEYS
from .driver import CAMERA_KEYS, Session, run_checks


def _check_screenshot(path, notice: str | None) -> None:
    from PIL import Image

    assert path is not None and Path(path).is_file(), f"no screenshot file ({notice})"
    img = np.asarray(Image.open(path).convert("RGB")).astype(int)
    assert img.reshape(-1, 3).std(axis=0).max() > 10, "the screenshot is one colour"
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    assert ((r > g + 50) & (g > b + 30)).sum() > 100, "the screenshot shows no (orange) body"


def _latest(pattern: str, before: set) -> Path | None:
    new = sorted(set(Path("out").glob(pattern)) - before)
    return new[-1] if new else None


def escape_check(s: Session):
    def escape_quits():
        s.x.key("Escape", True)
        s.frames(1)
        s.x.key("Escape", False)
        try:
            s.frames(2)
        except AssertionError:
            pass
        assert not s.app.window.running, "Esc did not close the window"

    return escape_quits


def check_every_control(s: Session) -> dict:
    """Press every advertised key and click panel buttons; returns control -> "ok" or the failure."""
    ctl, app = s.ctl, s.app
    s.calibrate()
    s.pointer_to_scene()
    s.frames(3)

    def start_paused():
        assert ctl.settings.paused and ctl.sim.time == 0.0, (ctl.settings.paused, ctl.sim.time)

    def space_plays():
        s.press(" ")
        assert not ctl.settings.paused, "Space did not start the run"
        for _ in range(200):  # a few frames that stepped: the plot has history to keep
            if ctl.sim.time >= 0.05 and len(ctl.history.t) >= 4:
                break
            s.frames(1)
        assert ctl.sim.time >= 0.05 and len(ctl.history.t) >= 4, (ctl.sim.time, ctl.history.t)

    def pause_keeps_history():
        s.press(" ")
        assert ctl.settings.paused, "Space did not pause"
        t, history = ctl.sim.time, list(ctl.history.t)
        assert len(history) >= 3, history
        s.frames(10)
        assert ctl.sim.time == t and list(ctl.history.t) == history, "the paused plot's history changed"

    def n_steps():
        t = ctl.sim.time
        s.press("n")
        assert ctl.settings.paused and math.isclose(ctl.sim.time, t + ctl.sim.dt), (t, ctl.sim.time)

    def m_slow_motion():
        s.press("m")
        assert ctl.settings.slow_motion == 0.25, ctl.settings.slow_motion
        s.press("m")
        assert ctl.settings.slow_motion == 1.0, ctl.settings.slow_motion

    def draw_keys():
        for key, name in DRAW_KEYS.items():
            before = app.draw[name]
            s.press(key)
            assert app.draw[name] != before, f"{key.upper()} did not toggle {name}"
            s.press(key)
            assert app.draw[name] == before, f"{key.upper()} did not toggle {name} back"

    def camera_keys():
        for key in CAMERA_KEYS:
            before = s.camera()[0]
            s.hold(key)
            assert np.abs(s.camera()[0] - before).max() > 1e-4, f"{key.upper()} did not move the camera"

    def right_drag():
        before = s.camera()
        front = before[1] - before[0]
        s.pointer_to_scene()
        s.frames(1)
        s.x.button("RMB", True)
        s.frames(1)
        s.move(round(0.35 * s.width) + 80, round(0.45 * s.height) + 40)
        s.frames(2)
        s.x.button("RMB", False)
        s.frames(1)
        after = s.camera()
        turned = after[1] - after[0]
        cos = np.dot(front, turned) / (np.linalg.norm(front) * np.linalg.norm(turned))
        assert cos < 0.9999, "right-drag did not turn the view"
        s.pointer_to_scene()

    def c_resets_camera():
        s.hold("w")
        s.press("c")
        want = app._default_camera()
        eye, target = s.camera()
        assert np.allclose(eye, want.position, atol=1e-4), (eye, want.position)

    def p_screenshot():
        before = set(Path("out").glob("*.png"))
        s.press("p")
        _check_screenshot(_latest("*.png", before), app.notice)

    def screenshot_button():
        before = set(Path("out").glob("*.png"))
        bands = s.buttons()
        s.click(bands[-2])  # "Screenshot (P)": the second-last button of the column
        s.frames(3)
        _check_screenshot(_latest("*.png", before), app.notice)

    def integrator_button():
        bands = s.buttons()
        names = ctl.integrator_names()
        expected = 3 + len(names) + len(ctl.terrain_kinds()) + 3
        assert len(bands) == expected, f"found {len(bands)} buttons in the panel, not {expected}: {bands}"
        s.click(bands[3 + names.index("rk4")])  # after Pause, Single step, Reset
        assert ctl.settings.integrator == "rk4" == ctl.sim.integrator_name, ctl.settings.integrator
        s.press(" ")
        t = ctl.sim.time
        s.frames(3)
        assert ctl.sim.time > t, "no steps with rk4"
        s.press(" ")

    def v_records():
        before = set(Path("out").glob("*.mp4"))
        s.press("v")
        assert app.recording is not None, app.notice
        s.frames(5)
        s.press("v")
        assert app.recording is None, "V did not stop the recording"
        path = _latest("*.mp4", before)
        assert path is not None and path.stat().st_size > 0, app.notice

    def r_restarts_paused():
        s.press(" ")
        s.frames(3)
        s.press("r")
        assert ctl.sim.time == 0.0 and ctl.settings.paused, (ctl.sim.time, ctl.settings.paused)

    escape_quits = escape_check(s)

    checks = (("start paused", start_paused), ("Space plays", space_plays),
              ("Space pauses, plot history kept", pause_keeps_history), ("N single step", n_steps),
              ("M slow motion", m_slow_motion), ("F O J K L draw toggles", draw_keys),
              ("W A S D Q E move the camera", camera_keys), ("right-drag turns the view", right_drag),
              ("C resets the camera", c_resets_camera), ("P screenshot", p_screenshot),
              ("Screenshot button", screenshot_button), ("integrator button", integrator_button),
              ("V records", v_records), ("R resets, paused", r_restarts_paused))
    return run_checks(app, checks), escape_quits
