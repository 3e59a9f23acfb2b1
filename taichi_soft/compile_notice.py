"""Says on stderr that a run is compiling Taichi kernels while it does, and how long they took.

Taichi compiles a kernel at its first launch in a process, or loads it from the offline kernel
cache when an earlier run compiled it. A first run of a scene and integrator on a machine can
compile one kernel for tens of seconds with nothing on the screen. Compiling holds Python's lock,
so no thread of this process can speak meanwhile: a small shell process is told when each first
launch starts and ends, and says so on stderr when one lasts longer than ``THRESHOLD_S``.
Loading the largest kernel from the cache, and its first step, take a few seconds; compiling it
cold takes several times that (docs/decisions/serial-step-ir-passes.md).

Used by the command line only (``install`` after ``runtime.init``; ``watch`` once the set-up is
done, so that an error in the set-up stays the only line a run prints).
"""
from __future__ import annotations

import os
import shlex
import subprocess
import sys
import time

THRESHOLD_S = 5  # [s] a kernel's first launch may take before the run says it is compiling

_state = {"installed": False, "watching": False, "longest": 0.0, "seconds": 0.0, "kernels": 0, "cache": ""}
_seen: set[int] = set()
_watchdog = {"proc": None}


def install(cache_dir: str) -> None:
    """Time every kernel's first launch in this process (idempotent); ``cache_dir`` is named in the notice."""
    _state["cache"] = cache_dir
    if _state["installed"]:
        return
    from taichi.lang.kernel_impl import Kernel

    launch = Kernel.launch_kernel

    def timed_launch(self, t_kernel, *args):
        if id(t_kernel) in _seen:
            return launch(self, t_kernel, *args)
        _seen.add(id(t_kernel))
        _tell("start")
        start = time.perf_counter()
        try:
            return launch(self, t_kernel, *args)
        finally:
            seconds = time.perf_counter() - start
            _tell("end")
            _state["seconds"] += seconds
            _state["kernels"] += 1
            if _state["watching"]:
                _state["longest"] = max(_state["longest"], seconds)

    Kernel.launch_kernel = timed_launch
    _state["installed"] = True


def watch() -> None:
    """From now on, say so on stderr when a kernel's first launch passes ``THRESHOLD_S``."""
    if _state["watching"] or not _state["installed"]:
        return
    message = (f"compiling Taichi kernels (a first run of this scene and integrator here; later runs load "
               f"them from the kernel cache {_state['cache']}) ...")
    # Waits for "end" at most THRESHOLD_S after each "start"; past it, says the message once.
    script = (f'said=0; while read -r cmd; do [ "$cmd" = start ] || continue; '
              f'read -r -t {THRESHOLD_S} cmd; rc=$?; [ $rc -eq 0 ] && continue; [ $rc -le 128 ] && exit 0; '
              f'[ $said = 0 ] && echo {shlex.quote(message)} >&2; said=1; read -r cmd || exit 0; done')
    try:
        _watchdog["proc"] = subprocess.Popen(["bash", "-c", script], stdin=subprocess.PIPE, stdout=subprocess.DEVNULL)
    except OSError:  # no bash: the run stays silent while it compiles, and still says so at its end
        _watchdog["proc"] = None
    _state["watching"] = True


def _tell(word: str) -> None:
    proc = _watchdog["proc"]
    if proc is None:
        return
    try:
        os.write(proc.stdin.fileno(), (word + "\n").encode())
    except OSError:
        _watchdog["proc"] = None


def summary() -> str | None:
    """How long the first launches took, if one of them since ``watch`` passed ``THRESHOLD_S``; else None."""
    proc = _watchdog["proc"]
    if proc is not None:
        proc.stdin.close()
        proc.wait()
        _watchdog["proc"] = None
    if _state["longest"] < THRESHOLD_S:
        return None
    return (f"Taichi kernels: {_state['kernels']} first launches took {_state['seconds']:.1f} s, most of it "
            f"compiling; later runs of this scene and integrator load them from the kernel cache")


def say_summary() -> None:
    """Print ``summary()`` on stderr, if there is one."""
    line = summary()
    if line:
        print(line, file=sys.stderr)
