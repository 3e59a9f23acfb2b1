"""The benchmarks' one timing helper: every timed number of ``taichi_soft.bench`` and of
``taichi_soft.render.benchmark`` comes from here.

Method, per candidate (a named piece of work):

* warm-up: ``warmup()`` once before any repeat (Taichi compiles a kernel on its first call), not timed;
* each repeat: ``setup()`` (reset the state; not timed), ``sync()``, read the clocks, ``run()``,
  ``sync()``, read the clocks again. ``sync`` is ``ti.sync()`` unless given (a kernel launch returns
  before the device has finished; numpy and other synchronous work pass ``no_sync``);
* several candidates are interleaved: one repeat of each in turn, round after round, the order
  rotated by one each round (``rotate``), so a drift of the machine's load hits all of them alike;
* ``done(result)`` (optional, not timed) after a repeat stops that candidate's repeats (a
  diverged run is not timed again);
* both clocks: wall (``time.perf_counter``) and this process's CPU time (``time.process_time``,
  all its threads), which a loaded machine distorts less.

``Timing`` keeps every sample; studies report its ``median`` (or ``min``, where a study says so).
"""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass, field
from typing import Callable


def ti_sync() -> None:
    """``ti.sync()``: wait until every launched Taichi kernel has finished (the default ``sync``)."""
    import taichi as ti

    ti.sync()


def no_sync() -> None:
    """For work that is done when it returns (numpy, Python)."""


@dataclass
class Candidate:
    """One piece of work to time: ``run()`` is timed; the rest is not."""

    run: Callable[[], object]
    setup: Callable[[], object] | None = None  # before each repeat (reset the state)
    warmup: Callable[[], object] | None = None  # once, before the first repeat (compiles)
    sync: Callable[[], None] = ti_sync  # before each clock reading
    done: Callable[[object], bool] | None = None  # after a repeat, given run()'s value: stop repeating


@dataclass
class Timing:
    """The samples of one candidate [s], in the order taken, and the last ``run()``'s value."""

    wall: list = field(default_factory=list)
    cpu: list = field(default_factory=list)
    last: object = None

    repeats = property(lambda self: len(self.wall))
    median = property(lambda self: statistics.median(self.wall))  # [s]
    min = property(lambda self: min(self.wall))  # [s]
    cpu_median = property(lambda self: statistics.median(self.cpu))  # [s] of process CPU time


def time_candidates(candidates: dict[str, Candidate], repeats: int, rotate: bool = True,
                    clock=time.perf_counter, cpu_clock=time.process_time) -> dict[str, Timing]:
    """Time every candidate ``repeats`` times, interleaved (see the module's docstring)."""
    for c in candidates.values():
        if c.warmup is not None:
            c.warmup()
            c.sync()
    out = {name: Timing() for name in candidates}
    live = list(candidates)
    for r in range(repeats):
        k = r % len(live) if rotate and live else 0
        for name in live[k:] + live[:k]:
            c, t = candidates[name], out[name]
            if c.setup is not None:
                c.setup()
            c.sync()
            t0, c0 = clock(), cpu_clock()
            t.last = c.run()
            c.sync()
            t.wall.append(clock() - t0)
            t.cpu.append(cpu_clock() - c0)
            if c.done is not None and c.done(t.last):
                live.remove(name)
        if not live:
            break
    return out


def time_one(run: Callable[[], object], repeats: int, **kwargs) -> Timing:
    """``time_candidates`` of one candidate; ``kwargs`` are ``Candidate``'s and ``clock``/``cpu_clock``."""
    clocks = {k: kwargs.pop(k) for k in ("clock", "cpu_clock") if k in kwargs}
    return time_candidates({"": Candidate(run, **kwargs)}, repeats, **clocks)[""]
