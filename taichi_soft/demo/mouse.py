"""The left mouse button on the body: grab and drag, poke, pin (the window feeds it, ``app``).

    press on the body          grab the particle under the cursor (``picking``): a spring pulls it
                               toward the cursor's point on the plane through the particle that
                               faces the camera (``DemoController.grab_particle`` / ``drag``)
    release                    let go; if the press was a quick click (under ``CLICK_SECONDS``
                               or by the next frame, the cursor moved at most ``CLICK_PIXELS``)
                               it was a poke: the particle gets a velocity kick along the view ray
    Shift + press, or pin mode pin the particle under the cursor where it is, or unpin it

Everything reaches the simulation through the controller's inputs, so a recorded session holds
the particle indices and world points, not pixels, and replays without a camera.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .picking import PICK_RADIUS, lattice_spacing, pick, plane_point, view_ray
from .surface_pick import SurfacePicker

CLICK_SECONDS = 0.25  # a press released sooner than this without moving is a poke ...
CLICK_FRAMES = 1  # ... or one released by the frame after the press (a slow window's quick click)
CLICK_PIXELS = 4  # cursor travel [px] that turns a press into a drag


@dataclass
class _Held:
    index: int
    anchor: np.ndarray  # the particle's position at the press [m]: the drag plane passes through it
    normal: np.ndarray  # the drag plane's normal: the camera's viewing direction at the press
    ray: np.ndarray  # the view ray's direction at the press (a poke's direction)
    pixel: tuple  # cursor at the press [px]
    start: float  # wall time of the press [s]
    moved: bool = False
    frames: int = 0  # frames since the press


class MouseHand:
    """Turns left-button presses, cursor motion and releases into grab / drag / poke / pin inputs.

    ``size``: the window (width, height) [px]; ``clock``: wall time [s] (tests pass their own).
    """

    def __init__(self, controller, size, clock=time.perf_counter):
        self.ctl = controller
        self.size = tuple(size)
        self.clock = clock
        self.pin_mode = False  # a plain press pins instead of grabbing (the I key)
        self.held: _Held | None = None
        self.last: str | None = None  # what the last press did, for the HUD

    def _picker(self) -> SurfacePicker:
        """The ray-surface picker of the current simulation's model (a terrain switch builds a new one)."""
        model = self.ctl.sim.model
        if getattr(self, "_picker_model", None) is not model:
            self._surface_picker = SurfacePicker(model)
            self._picker_model = model
        return self._surface_picker

    def _ray(self, cursor, cam):
        return view_ray(cam, cursor[0], cursor[1], self.size[0] / self.size[1])

    def _pixel(self, cursor) -> tuple:
        return (cursor[0] * self.size[0], (1 - cursor[1]) * self.size[1])

    def press(self, cursor, cam, shift: bool = False) -> int | None:
        """Left button down at ``cursor`` (GGUI's (u, v), v up) seen by camera ``cam`` (a
        ``CameraSpec``); returns the particle picked, or None if the ray missed the body."""
        origin, direction = self._ray(cursor, cam)
        hit = self._picker().pick(self.ctl.sim.state.x, origin, direction)
        if hit is None:  # off the surface: the particle nearest the ray, if close (an edge, a corner)
            points = self.ctl.sim.state.x.to_numpy().astype(np.float64, copy=False)
            i = pick(points, origin, direction, PICK_RADIUS * lattice_spacing(self.ctl.sim.model))
            hit = None if i is None else (i, points[i].copy())
        if hit is None:
            self.last = None
            return None
        i, at = hit
        if shift or self.pin_mode:
            self.ctl.toggle_pin(i)
            self.last = f"{'pinned' if i in self.ctl.pins else 'unpinned'} particle {i}"
            return i
        forward = np.subtract(cam.lookat, cam.position)
        forward /= np.linalg.norm(forward)
        self.held = _Held(i, at, forward, direction, self._pixel(cursor), self.clock())
        self.ctl.grab_particle(i, at)
        self.last = f"grabbed particle {i}"
        return i

    def motion(self, cursor, cam):
        """The cursor is at ``cursor`` this frame: move the held particle's target there."""
        h = self.held
        if h is None:
            return
        h.frames += 1
        px = self._pixel(cursor)
        if not h.moved and max(abs(px[0] - h.pixel[0]), abs(px[1] - h.pixel[1])) > CLICK_PIXELS:
            h.moved = True
        if not h.moved:
            return
        origin, direction = self._ray(cursor, cam)
        target = plane_point(origin, direction, h.anchor, h.normal)
        if target is not None:
            self.ctl.drag(target)

    def release(self):
        """Left button up: let go; a quick click without a drag pokes the particle."""
        h, self.held = self.held, None
        if h is None:
            return
        self.ctl.release()
        if not h.moved and (self.clock() - h.start < CLICK_SECONDS or h.frames <= CLICK_FRAMES):
            self.ctl.poke(h.index, h.ray)
            self.last = f"poked particle {h.index}"

    def warm(self):
        """Compile what a press runs (the positions' read-back, the grab's field writes) now,
        while the window is being set up, not in the first press's frame (measured: 160 ms)."""
        self.ctl.sim.state.x.to_numpy()
        self.ctl.grab.move(self.ctl.grab.target.to_numpy())
        self._picker().pick(self.ctl.sim.state.x, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))

    def cancel(self):
        """Forget a press without acting on it (the simulation was replaced or reset)."""
        self.held = None
