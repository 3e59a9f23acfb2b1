"""The demo's frame timer: wall time of each part of a frame, medians over the last frames.

    with timer.part("simulation"):
        ...
    timer.end_frame()
    timer.medians_ms()  ->  {"input": 0.05, "simulation": 8.1, ...}

Parts (``PARTS``): input (keys, picking and dragging), simulation (the steps), read-back (energy
measures and copying the state onto the draw fields), draw (scene, HUD and panel recorded into
the frame), show (GGUI renders and presents the frame). A part's time is taken after a
``ti.sync()``, so work a kernel launched asynchronously is counted where it ran.
"""
from __future__ import annotations

import time
from collections import deque
from contextlib import contextmanager

import numpy as np

PARTS = ("input", "simulation", "read-back", "draw", "show")


class FrameTimer:
    """Per-part wall times [s] of the last ``keep`` frames."""

    def __init__(self, keep: int = 120, clock=time.perf_counter, sync=None):
        self.clock = clock
        self.sync = sync  # e.g. ti.sync: called before each reading of the clock
        self.frames: deque = deque(maxlen=keep)
        self._current: dict = {}

    @contextmanager
    def part(self, name: str):
        start = self.clock()
        try:
            yield
        finally:
            if self.sync is not None:
                self.sync()
            self._current[name] = self._current.get(name, 0.0) + self.clock() - start

    def end_frame(self):
        self.frames.append(self._current)
        self._current = {}

    def medians_ms(self) -> dict:
        """Median milliseconds of each part (and the ``total``) over the frames kept."""
        if not self.frames:
            return {}
        table = {p: [f.get(p, 0.0) for f in self.frames] for p in PARTS}
        out = {p: 1e3 * float(np.median(v)) for p, v in table.items()}
        out["total"] = 1e3 * float(np.median([sum(f.values()) for f in self.frames]))
        return out

    def text(self) -> str:
        """One HUD line: "frame 21.3 ms = input 0.04 + simulation 9.1 + ..." (medians)."""
        m = self.medians_ms()
        if not m:
            return "frame: no frames timed yet"
        return f"frame {m['total']:.1f} ms = " + " + ".join(f"{p} {m[p]:.2f}" for p in PARTS)
