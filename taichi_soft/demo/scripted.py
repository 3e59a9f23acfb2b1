"""The demo driven by real X input, as a teacher would drive it: every advertised control checked.

    DISPLAY=:1 python -m taichi_soft.demo.scripted [--scene plane] [--set body.0.n=3 ...]
                                                   [--resolution 1024x640] [--minutes M]

Opens the demo window (started paused) and presses every key the HUD advertises and clicks
panel buttons through the X server (``xinput.XInput``, XTest), checking after each what it did to
the demo's state; screenshots and a recording go to ``out/`` under the working directory. With
``--minutes M`` it then keeps pressing random keys and clicking random buttons for M minutes (a
soak test). Prints one JSON object (``checks``: control -> "ok" or what went wrong; ``actions``:
the soak's counts of keys, clicks, recordings and switches) and exits 0 only if every check passed. Needs an X display (Xvfb will do) in
which the window is the only one, at the top-left corner.
"""
from __future__ import annotations

import argparse
import json
import math
import random
import sys
import time
from pathlib import Path

import numpy as np

from ..render.camera import project
from ..render.window import window_rgb
from .app import DRAW_KEYS, PANEL_X

CAMERA_KEYS = ("w", "a", "s", "d", "q", "e")


def button_bands(img: np.ndarray, x0: int) -> list[tuple[int, int]]:
    """Rows (first, last) of the ImGui buttons in the panel column starting at pixel ``x0``.

    A button row: the 24 pixels from 9 px into the column are all ImGui's button blue or its
    white label (antialiased: bluish), at least a quarter of them pure blue; a button is 12 or
    more such rows, below the 19-px title bar. Checkbox frames are a darker blue, and a
    checkbox row also holds the dark panel background.
    """
    px = img[:, x0 + 9:x0 + 33].astype(int)  # within the narrowest button ("rk4")
    r, g, b = px[..., 0], px[..., 1], px[..., 2]
    pure = (b > 95) & (b - r > 55) & (g - r > 20) & (r < 90)
    label = (px.min(axis=-1) > 110) | ((b > 95) & (b - r > 20))
    blue = (pure.mean(axis=1) >= 0.25) & ((pure | label).mean(axis=1) > 0.9)
    blue[:20] = False
    bands, start = [], None
    for y, on in enumerate(np.append(blue, False)):
        if on and start is None:
            start = y
        elif not on and start is not None:
            if y - start >= 12:
                bands.append((start, y - 1))
            start = None
    return bands


class Session:
    """A ``DemoApp`` and an ``XInput`` on its display, stepped frame by frame."""

    def __init__(self, app, xin):
        self.app, self.x = app, xin
        self.width, self.height = app.size
        self.image = None
        self.origin = (0, 0)  # screen pixel of the window's top-left corner (``calibrate``)

    def calibrate(self):
        """Find where the window sits on the screen (GLFW places it at (100, 100) here): move the
        pointer, read where the window saw it."""
        for _ in range(3):
            at = (self.origin[0] + self.width // 2, self.origin[1] + self.height // 2)
            self.x.move(*at)
            self.frames(3)
            u, v = self.app.window.get_cursor_pos()  # [0, 1], y up
            seen = (round(u * self.width), round((1 - v) * self.height))
            self.origin = (self.origin[0] + self.width // 2 - seen[0], self.origin[1] + self.height // 2 - seen[1])
            if seen == (self.width // 2, self.height // 2):
                return
        raise AssertionError(f"the window does not see the pointer where expected (origin {self.origin})")

    def move(self, x: int, y: int):
        """Pointer to pixel (x, y) of the window."""
        self.x.move(self.origin[0] + x, self.origin[1] + y)

    @property
    def ctl(self):
        return self.app.ctl

    def frames(self, n: int = 1, capture: bool = False):
        for _ in range(n):
            if not self.app.window.running:
                raise AssertionError("the window closed")
            self.app.frame()
            if capture:
                self.image = window_rgb(self.app.window)  # the frame as drawn, panel included
            self.app.show()

    def press(self, key: str, frames: int = 2):
        self.x.key(key, True)
        self.frames(1)
        self.x.key(key, False)
        self.frames(frames)

    def hold(self, key: str, frames: int = 3):
        self.x.key(key, True)
        self.frames(frames)
        self.x.key(key, False)
        self.frames(1)

    def buttons(self) -> list[tuple[int, int]]:
        """Centre pixels (x, y) of the buttons of the first panel column, top to bottom."""
        self.pointer_to_scene()
        self.frames(2, capture=True)
        x0 = round(PANEL_X * self.width)
        mid = x0 + 30
        return [(mid, (a + b) // 2) for a, b in button_bands(self.image, x0)]

    def click(self, at: tuple[int, int], frames: int = 2):
        self.move(*at)
        self.frames(2)
        self.x.button("LMB", True)
        self.frames(1)
        self.x.button("LMB", False)
        self.frames(frames)
        self.pointer_to_scene()

    def pointer_to_scene(self):
        """Pointer over the 3D view (X gives keyboard focus to the window under the pointer)."""
        self.move(round(0.35 * self.width), round(0.45 * self.height))

    def camera(self) -> tuple[np.ndarray, np.ndarray]:
        c = self.app.camera
        return c.curr_position.to_numpy().astype(float), c.curr_lookat.to_numpy().astype(float)

    def pixel(self, point) -> tuple[int, int]:
        """The window pixel (x, y) where world ``point`` [m] is drawn now."""
        col, row = project(np.asarray(point, float)[None], self.app.cam_spec, self.width, self.height)[0]
        return round(col), round(row)

    def positions(self) -> np.ndarray:
        return self.ctl.sim.state.x.to_numpy().astype(float)

    def until(self, condition, max_frames: int = 30) -> bool:
        """Frames until ``condition()`` holds (X events reach the window a frame or more late on
        a loaded machine); returns whether it came true."""
        for _ in range(max_frames):
            if condition():
                return True
            self.frames(1)
        return condition()

    def run_for(self, seconds: float, max_frames: int = 5000, during=None):
        """Frames until the simulation has advanced ``seconds`` [s] (it must be playing);
        ``during(k)`` is called before frame k."""
        if self.ctl.message:  # stopped (diverged): nothing more will run
            return
        if self.ctl.settings.paused:
            raise AssertionError("the simulation is paused")
        end = self.ctl.sim.time + seconds - 1e-9
        for k in range(max_frames):
            if self.ctl.sim.time >= end or self.ctl.message:
                return
            if during is not None:
                during(k)
            self.frames(1)
        raise AssertionError(f"{seconds} s did not pass in {max_frames} frames (t = {self.ctl.sim.time})")


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


def run_checks(app, checks) -> dict:
    """Run each (name, fn) in turn while the window is open; returns name -> "ok" or the failure
    (every check is reported, not just the first failure)."""
    results = {}
    for name, fn in checks:
        if not app.window.running:
            results[name] = "not run: the window closed"
            continue
        try:
            fn()
            results[name] = "ok"
        except Exception as e:  # noqa: BLE001
            results[name] = f"{type(e).__name__}: {e}".splitlines()[0]
    return results


def _escape_check(s: Session):
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

    escape_quits = _escape_check(s)

    checks = (("start paused", start_paused), ("Space plays", space_plays),
              ("Space pauses, plot history kept", pause_keeps_history), ("N single step", n_steps),
              ("M slow motion", m_slow_motion), ("F O J K L draw toggles", draw_keys),
              ("W A S D Q E move the camera", camera_keys), ("right-drag turns the view", right_drag),
              ("C resets the camera", c_resets_camera), ("P screenshot", p_screenshot),
              ("Screenshot button", screenshot_button), ("integrator button", integrator_button),
              ("V records", v_records), ("R resets, paused", r_restarts_paused))
    return run_checks(app, checks), escape_quits


def top_corners(s: Session) -> list[int]:
    """The body's four top corners (the 8 particles farthest from its centre, the 4 highest),
    nearest the camera first."""
    x = s.positions()
    c = x.mean(axis=0)
    corners = np.argsort(-np.linalg.norm(x - c, axis=1))[:8]
    top = corners[np.argsort(-x[corners, 1])[:4]]
    eye = np.asarray(s.app.cam_spec.position)
    return [int(i) for i in top[np.argsort(np.linalg.norm(x[top] - eye, axis=1))]]


def check_hands(s: Session, yank_integrator: str = "explicit_euler", yank_dt: float = 2e-3,
                yank_k: float = 1e5) -> tuple[dict, dict]:
    """The mouse on the body, through real X input: pin two top corners and let it hang, clear the
    pins, drag a top corner up and let go, poke, and a hard yank with ``yank_integrator`` at
    ``yank_dt`` [s] and grab stiffness ``yank_k`` [N/m]. The scene must start with the body in the
    air above the floor, paused. Returns (check -> "ok" or the failure, {"yank": "held" or
    "diverged, reset"})."""
    ctl, app = s.ctl, s.app
    s.calibrate()
    s.pointer_to_scene()
    s.frames(3)

    def click_particle(i, shift=False):
        s.move(*s.pixel(s.positions()[i]))
        s.frames(1)
        if shift:
            s.x.key("Shift", True)
            s.frames(1)
        s.x.button("LMB", True)
        s.frames(1)
        s.x.button("LMB", False)
        s.frames(1)
        if shift:
            s.x.key("Shift", False)
            s.frames(1)

    def pins_hold_and_hang():
        assert ctl.settings.paused and ctl.sim.time == 0.0, "the session must start paused"
        a, b = top_corners(s)[:2]
        click_particle(a, shift=True)
        s.until(lambda: len(ctl.pins) == 1)
        click_particle(b, shift=True)
        s.until(lambda: len(ctl.pins) == 2)
        assert ctl.pins == {a, b}, f"Shift+click pinned {sorted(ctl.pins)}, not the corners {a}, {b}"
        assert ctl.sim.time == 0.0, "pinning stepped the simulation"
        x0 = s.positions()
        s.press(" ")
        s.run_for(2.0)
        assert ctl.message is None, ctl.message
        x = s.positions()
        moved = float(np.abs(x[[a, b]] - x0[[a, b]]).max())
        assert moved <= 1e-9, f"the pinned corners moved {moved:.3g} m"
        free = np.setdiff1d(np.arange(len(x)), [a, b])
        pin_y = x0[[a, b], 1].mean()
        assert x[free, 1].mean() < pin_y - 0.2, "the body does not hang below its pins"
        # hanging, not fallen: the free particles stay within the body's reach of the pins
        assert x[free, 1].min() > pin_y - 2.5 * np.ptp(x0[:, 1]) - 0.5, "the body fell away from its pins"
        s.pins_y = pin_y

    def x_clears_pins_and_it_falls():
        com0 = s.positions()[:, 1].mean()
        s.press("x")
        assert not ctl.pins, f"X left pins {sorted(ctl.pins)}"
        s.run_for(0.3)
        assert s.positions()[:, 1].mean() < com0 - 0.1, "after X the body did not fall"
        s.run_for(2.0)  # lands and settles for the drag

    def reset_clears_pins():
        click_particle(top_corners(s)[0], shift=True)
        assert s.until(lambda: len(ctl.pins) == 1), ctl.pins
        s.press("r")
        assert not ctl.pins and ctl.sim.time == 0.0, (ctl.pins, ctl.sim.time)
        s.press(" ")
        s.run_for(2.5)  # falls, lands, settles

    def drag_up_and_release():
        corner = top_corners(s)[0]
        x0 = s.positions()
        px, py = s.pixel(x0[corner])
        s.move(px, py)
        s.frames(1)
        s.x.button("LMB", True)
        s.until(lambda: ctl.grab.held is not None)
        assert ctl.grab.held == corner, f"the press grabbed {ctl.grab.held}, not the corner {corner}"
        start = ctl.sim.time
        s.run_for(1.0, during=lambda k: s.move(px, py - min(150, 15 * (k + 1))))
        x1 = s.positions()
        target = ctl.grab.target.to_numpy()
        assert target[1] > x0[corner, 1] + 0.3, f"150 px up put the target only at {target}"
        assert x1[corner, 1] > x0[corner, 1] + 0.2, f"the corner rose only {x1[corner, 1] - x0[corner, 1]:.3f} m"
        others = np.setdiff1d(np.arange(len(x1)), [corner])
        assert x1[others, 1].mean() > x0[others, 1].mean() + 0.05, "the body did not follow the corner"
        assert ctl.sim.time >= start + 1.0
        s.x.button("LMB", False)
        assert s.until(lambda: ctl.grab.held is None), "release did not let go"
        s.run_for(1.5)
        x2 = s.positions()
        assert x2[corner, 1] < x1[corner, 1] - 0.15, "the corner did not fall back"
        assert abs(x2[:, 1].mean() - x0[:, 1].mean()) < 0.1, "the body did not come back to rest on the floor"

    def click_pokes():
        corner = top_corners(s)[0]
        s.press(" ")  # pause: the kick is read before any step damps it
        assert ctl.settings.paused
        v0 = ctl.sim.state.v.to_numpy()[corner].astype(float)
        eye = np.asarray(app.cam_spec.position)
        click_particle(corner)
        s.until(lambda: np.any(ctl.sim.state.v.to_numpy()[corner] != v0) and ctl.grab.held is None)
        dv = ctl.sim.state.v.to_numpy()[corner] - v0
        ray = s.positions()[corner] - eye
        ray /= np.linalg.norm(ray)
        speed = ctl.settings.poke_speed
        assert abs(np.linalg.norm(dv) - speed) < 1e-6 * speed, f"the poke added {np.linalg.norm(dv)} m/s, not {speed}"
        assert dv @ ray > 0.99 * speed, "the poke is not along the view ray"
        assert ctl.grab.held is None
        s.press(" ")
        s.run_for(0.5)

    def hard_yank():
        ctl.set_integrator(yank_integrator)  # set up as the panel would: integrator, dt, grab k
        ctl.set_dt(yank_dt)
        ctl.set_grab_stiffness(yank_k)
        corner = top_corners(s)[0]
        px, py = s.pixel(s.positions()[corner])
        s.move(px, py)
        s.frames(1)
        s.x.button("LMB", True)
        assert s.until(lambda: ctl.grab.held is not None), "the press grabbed nothing"
        s.move(px, max(py - 300, 5))
        s.run_for(1.0)
        s.x.button("LMB", False)
        s.frames(2)
        assert app.window.running, "the window closed"
        if ctl.message:  # diverged: the demo says so and R recovers
            assert ctl.message.startswith("diverged") and "R resets" in ctl.message, ctl.message
            s.press("r")
            assert ctl.message is None and ctl.sim.time == 0.0
            s.press(" ")
            s.run_for(0.2)
            assert np.isfinite(s.positions()).all()
            s.result = "diverged, reset"
        else:
            assert np.isfinite(s.positions()).all(), "non-finite state without a divergence message"
            s.result = "held"

    checks = (("Shift+click pins two corners, it hangs", pins_hold_and_hang),
              ("X clears the pins, it falls", x_clears_pins_and_it_falls),
              ("R clears pins", reset_clears_pins),
              ("drag a top corner up, release", drag_up_and_release),
              ("click pokes", click_pokes),
              (f"hard yank with {yank_integrator} at dt {yank_dt:g} s", hard_yank))
    return run_checks(app, checks), {"yank": getattr(s, "result", None)}


def measure_timing(s: Session, blocks: int = 4, frames: int = 30) -> dict:
    """The frame timer's breakdown [ms, medians] while playing, alternating blocks of ``frames``
    frames with the body left alone and with its top face's centre grabbed and dragged (the pointer moving
    every frame); also the press frames' input part (picking) and each block's cost per step."""
    ctl, app = s.ctl, s.app
    s.calibrate()
    s.pointer_to_scene()
    if ctl.settings.paused:
        s.press(" ")
    s.frames(10)  # warm: every kernel compiled
    out = {"idle": [], "drag": [], "press_input_ms": []}
    for b in range(2 * blocks):
        mode = "idle" if b % 2 == 0 else "drag"
        if mode == "drag":
            x = s.positions()
            top = int(np.argmin(np.linalg.norm(x - [x[:, 0].mean(), x[:, 1].max(), x[:, 2].mean()], axis=1)))
            px, py = s.pixel(x[top])  # the top face's centre: well inside the silhouette
            s.move(px, py)
            s.frames(1)
            s.x.button("LMB", True)
            assert s.until(lambda: ctl.grab.held is not None), "the press grabbed nothing"
            out["press_input_ms"].append(1e3 * app.timer.frames[-1].get("input", 0.0))
        app.timer.frames.clear()
        steps0 = ctl.sim.steps
        for k in range(frames):
            if mode == "drag":
                s.move(px + (k % 10) * 3, py - 3 * k)
            s.frames(1)
        m = app.timer.medians_ms()
        m["ms_per_step"] = m["simulation"] * frames / max(ctl.sim.steps - steps0, 1)
        out[mode].append(m)
        if mode == "drag":
            s.x.button("LMB", False)
            s.frames(2)
    summary = {mode: {k: float(np.median([m[k] for m in out[mode]])) for k in out[mode][0]} for mode in ("idle", "drag")}
    summary["press_input_ms"] = out["press_input_ms"]
    return summary


def soak(s: Session, minutes: float, seed: int = 0) -> dict:
    """Random keys and button clicks for ``minutes``; returns how many of each kind were done
    (``keys``, ``clicks``, ``recordings`` toggled, and the ``integrators`` and ``terrains``
    switched to).

    Raises if the window closes or the state stops being finite without a divergence message.
    """
    rng = random.Random(seed)
    keys = [" ", "n", "r", "m", "c", "p", *DRAW_KEYS, *CAMERA_KEYS]
    end = time.monotonic() + 60 * minutes
    done = {"keys": 0, "clicks": 0, "recordings": 0, "integrators": 0, "terrains": 0}
    bands = s.buttons()
    while time.monotonic() < end:
        roll = rng.random()
        before = (s.ctl.settings.integrator, s.ctl.settings.terrain)
        if roll < 0.55:
            s.press(rng.choice(keys), frames=rng.randint(1, 5))
            done["keys"] += 1
        elif roll < 0.9:
            # Any button but the last (recording: toggled below, rarely, so files stay small).
            s.click(rng.choice(bands[:-1]), frames=rng.randint(1, 5))
            bands = s.buttons()  # a terrain switch or a label change may move them
            done["clicks"] += 1
        else:
            s.press("v", frames=rng.randint(5, 20))
            done["recordings"] += 1
        done["integrators"] += s.ctl.settings.integrator != before[0]
        done["terrains"] += s.ctl.settings.terrain != before[1]
        if not s.app.window.running:
            raise AssertionError(f"the window closed after {done}")
        m = s.ctl.last_measures
        if m is not None and not s.ctl.message:
            assert np.isfinite(m["total_energy"]), "non-finite energy without a divergence message"
    if s.app.recording is not None:
        s.press("v")
    return done


def main(argv=None) -> int:
    from ..runtime import init
    from ..scene_validation import parse_resolution
    from .app import DemoApp
    from .controller import DemoController
    from .display import open_demo_window
    from .xinput import XInput

    p = argparse.ArgumentParser(prog="python -m taichi_soft.demo.scripted", description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="plane")
    p.add_argument("--set", action="append", default=[])
    p.add_argument("--resolution", default="1024x640")
    p.add_argument("--minutes", type=float, default=0.0, help="soak test length after the checks")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--hands", action="store_true",
                   help="check the mouse on the body (pins, drag, poke, yank) instead of the keys and buttons")
    p.add_argument("--yank", default="explicit_euler:0.002:1e5", metavar="INTEGRATOR:DT:K",
                   help="--hands: the hard yank's integrator, dt [s] and grab stiffness [N/m]")
    p.add_argument("--record", metavar="SESSION.json", help="record the session's inputs (as demo --record)")
    p.add_argument("--timing", action="store_true",
                   help="measure the frame timer's breakdown idle and while dragging; print it and exit")
    args = p.parse_args(argv)
    size = parse_resolution(args.resolution)
    init("cpu", "f64")
    window = open_demo_window("taichi-soft demo", size, fps_limit=1000)
    app = DemoApp(DemoController(args.scene, args.set, "semi_implicit_euler", paused=True), size, window)
    if args.record:
        from .app import start_session

        start_session(app, args.record)
    xin = XInput()
    session = Session(app, xin)
    report = {"checks": {}, "actions": {}}
    try:
        if args.timing:
            report["timing"] = measure_timing(session)
            escape = _escape_check(session)
        elif args.hands:
            name, dt, k = args.yank.split(":")
            report["checks"], report["actions"] = check_hands(session, name, float(dt), float(k))
            escape = _escape_check(session)
        else:
            report["checks"], escape = check_every_control(session)
        if args.minutes > 0 and app.window.running:
            try:
                report["actions"] = soak(session, args.minutes, args.seed)
                report["checks"]["soak"] = "ok"
            except Exception as e:  # noqa: BLE001
                report["checks"]["soak"] = f"{type(e).__name__}: {e}".splitlines()[0]
        if app.window.running:
            try:
                escape()
                report["checks"]["Esc quits"] = "ok"
            except Exception as e:  # noqa: BLE001
                report["checks"]["Esc quits"] = f"{type(e).__name__}: {e}".splitlines()[0]
    finally:
        if app.recording is not None:
            app.toggle_recording()
        app.close_session()
        app.window.destroy()
        xin.close()
    report["final"] = {"time": app.ctl.sim.time, "steps": app.ctl.sim.steps}
    print(json.dumps(report))
    return 0 if all(v == "ok" for v in report["checks"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
