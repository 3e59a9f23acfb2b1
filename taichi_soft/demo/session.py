"""Recorded demo sessions: ``demo --record session.json`` saves the inputs, ``demo --replay`` plays
them back without a display into a video.

What is recorded is every *input* to the simulation, as ``DemoController`` receives it (its
``@recorded`` methods: keys, buttons, sliders, grabs with their particle and world target, pokes,
pins, and ``step(n)`` with the number of steps each frame took), in order, grouped by the frame in
which they happened, with the frame's wall-clock time [s since the first frame], camera and draw
toggles. Replaying calls the same methods with the same arguments, so the simulation takes the
same steps with the same inputs and ends in the same state (the file keeps the live session's final
positions and the replay checks them); the video shows each frame for as long as it was on screen
live.

File (JSON): {"format", "version", "setup": {scene, overrides, integrator, dt, paused, duration,
resolution, arch, precision, fast_math}, "frames": [{"t", "ops": [[name, args, kwargs], ...], "camera": [eye, lookat, up, fov],
"draw": {...}}], "final": {"time", "steps", "x"}}.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from ..errors import UserError

FORMAT = "taichi-soft demo session"
VERSION = 1


class SessionRecorder:
    """Collects a live session's inputs (``controller.recorder = self``) and writes them on ``close``."""

    def __init__(self, path, setup: dict, clock=time.perf_counter):
        self.path = Path(path)
        self.setup = dict(setup)
        self.clock = clock
        self.frames: list[dict] = []
        self._ops: list = []  # inputs since the last frame was shown
        self._start = None
        self._draw = None

    def input(self, name: str, args: list, kwargs: dict):
        """One controller input (called by ``live_controls.recorded``)."""
        self._ops.append([name, _plain(args), _plain(kwargs)])

    def end_frame(self, app):
        """The frame ``app`` just drew is being shown: close its entry."""
        now = self.clock()
        if self._start is None:
            self._start = now
        cam = app.cam_spec
        entry = {"t": now - self._start, "ops": self._ops,
                 "camera": [list(map(float, cam.position)), list(map(float, cam.lookat)), list(map(float, cam.up)),
                            float(cam.fov)]}
        if app.draw != self._draw:
            entry["draw"] = dict(app.draw)
            self._draw = dict(app.draw)
        self.frames.append(entry)
        self._ops = []

    def close(self, controller) -> Path:
        """Write the session with the simulation's final state; the file appears whole or not at all."""
        if self._ops:  # inputs after the last frame shown
            self.frames.append({"t": self.frames[-1]["t"] if self.frames else 0.0, "ops": self._ops})
            self._ops = []
        sim = controller.sim
        data = {"format": FORMAT, "version": VERSION, "setup": self.setup, "frames": self.frames,
                "final": {"time": sim.time, "steps": sim.steps, "message": controller.message,
                          "x": sim.state.x.to_numpy().astype(np.float64).tolist()}}
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        try:
            with open(tmp, "w") as f:
                json.dump(data, f)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        finally:
            tmp.unlink(missing_ok=True)
        return self.path


def _plain(value):
    """JSON-ready copies of input arguments (numpy arrays and scalars to lists and floats)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def load_session(path) -> dict:
    """Read and check a session file; ``UserError`` (one line) if it is not one we can replay."""
    from .controller import DemoController

    p = Path(path)
    try:
        data = json.loads(p.read_text())
    except FileNotFoundError:
        raise UserError(f"--replay {path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise UserError(f"--replay {path}: not a readable session file ({e})".splitlines()[0]) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise UserError(f"--replay {path}: not a taichi-soft demo session (record one with demo --record)")
    if data.get("version") != VERSION:
        raise UserError(f"--replay {path}: session version {data.get('version')!r}, this demo reads {VERSION}")
    setup, frames = data.get("setup"), data.get("frames")
    if not isinstance(setup, dict) or not isinstance(frames, list) or "scene" not in setup:
        raise UserError(f"--replay {path}: the session has no setup or frames")
    for k, frame in enumerate(frames):
        for op in frame.get("ops", []):
            name = op[0] if isinstance(op, list) and len(op) == 3 else None
            if not (isinstance(name, str) and getattr(getattr(DemoController, name, None), "recorded", False)):
                raise UserError(f"--replay {path}: frame {k} holds an unknown input {op!r:.60}")
    return data
