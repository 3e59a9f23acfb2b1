"""The demo window driven frame by frame through real X input (``scripted``'s driver): a
``Session`` holds a ``DemoApp`` and an ``XInput`` on its display and steps, presses, clicks and
reads the window; ``button_bands`` finds the panel's buttons in a frame; ``run_checks`` runs named
checks while the window is open.
"""
from __future__ import annotations

import numpy as np

from taichi_soft.render.camera import project
from taichi_soft.render.window import window_rgb
from taichi_soft.demo.panel import PANEL_X

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
