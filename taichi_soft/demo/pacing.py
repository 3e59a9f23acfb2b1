"""How many steps each frame takes so that simulated time keeps pace with the wall clock.

Each frame wants ``slow_motion x (wall time since the last frame)`` simulated seconds, i.e.
1 / (display rate x dt) steps at full speed, with the fractional step carried to the next frame
so nothing drifts. The physics of one frame is capped at ``budget`` wall seconds (estimated from
the measured cost of a step) so the window stays responsive; what the cap cuts is dropped, not
owed, and the HUD then reports how far behind real time the simulation runs.
"""
from __future__ import annotations

import time
from collections import deque

MAX_FRAME_GAP = 0.25  # s: a longer pause (window dragged, compile) is not caught up


class Pacer:
    """Steps per frame from the wall clock; also measures steps/s and the real-time factor.

    ``budget`` [s]: most wall time a frame may spend stepping. ``window`` [s]: how far back the
    steps/s and real-time factor average.
    """

    def __init__(self, budget: float = 0.05, window: float = 1.0, clock=time.perf_counter):
        self.budget, self.window, self.clock = budget, window, clock
        self.step_cost = None  # s per step, smoothed; None until measured
        self._carry = 0.0  # simulated seconds owed to the next frame
        self._last = None
        self.limited = False  # True when the last frame was cut by the budget
        self._samples: deque = deque()  # (wall time, steps, simulated seconds)

    def plan(self, dt: float, slow_motion: float = 1.0) -> int:
        """Steps to take this frame for time step ``dt`` [s] (call once per frame)."""
        now = self.clock()
        gap = 0.0 if self._last is None else min(now - self._last, MAX_FRAME_GAP)
        self._last = now
        self._carry += slow_motion * gap
        n = int(self._carry / dt + 1e-9)
        cap = n if self.step_cost is None else max(1, int(self.budget / self.step_cost))
        self.limited = n > cap
        if self.limited:
            n, self._carry = cap, 0.0  # drop the backlog: catching up would only fall further behind
        else:
            self._carry -= n * dt
        return n

    def pause(self):
        """Forget the time that passed while paused (call every paused frame)."""
        self._last, self._carry = None, 0.0
        self.limited = False

    def record(self, steps: int, seconds: float, dt: float):
        """Report that ``steps`` steps of ``dt`` [s] took ``seconds`` of wall time."""
        if steps > 0:
            cost = seconds / steps
            self.step_cost = cost if self.step_cost is None else 0.7 * self.step_cost + 0.3 * cost
        now = self.clock()
        self._samples.append((now, steps, steps * dt))
        while self._samples and now - self._samples[0][0] > self.window:
            self._samples.popleft()

    def _span(self) -> float:
        if len(self._samples) < 2:
            return 0.0
        return self._samples[-1][0] - self._samples[0][0]

    @property
    def steps_per_second(self) -> float:
        """Steps per wall-clock second over the last ``window`` (0 before two frames)."""
        span = self._span()
        return sum(s[1] for s in list(self._samples)[1:]) / span if span > 0 else 0.0

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second over the last ``window`` (1 = real time)."""
        span = self._span()
        return sum(s[2] for s in list(self._samples)[1:]) / span if span > 0 else 0.0
