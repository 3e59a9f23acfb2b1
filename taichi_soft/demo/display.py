"""Opening the demo's visible window, or saying in one line why it cannot be opened.

Two things can be missing: a display (GLFW then aborts the whole process with "cannot initialize
GLFW", so it is probed first, without GLFW) and a Vulkan device (GGUI raises a RuntimeError and
its C++ side prints more lines to stderr, which are kept out of the terminal).
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import sys
import tempfile
from pathlib import Path

from ..errors import UserError

FALLBACK = "render offline instead: python main.py run --video out/demo.mp4"


def display_problem() -> str | None:
    """Why no window can be shown here, or None if a display answers."""
    if sys.platform != "linux":
        return None  # macOS and Windows always have a desktop session for a local user
    wayland = os.environ.get("WAYLAND_DISPLAY")
    if wayland:
        runtime_dir = os.environ.get("XDG_RUNTIME_DIR", "")
        if Path(wayland).is_absolute() and Path(wayland).exists() or Path(runtime_dir, wayland).exists():
            return None
    display = os.environ.get("DISPLAY")
    if not display:
        return "no display: DISPLAY is not set (a desktop session, ssh -X or Xvfb provides one)"
    return None if _x_display_answers(display) else f"no display: the X server at DISPLAY={display} does not answer"


def _x_display_answers(display: str) -> bool:
    """Open and close an X connection with libX11 (what GLFW itself would do)."""
    name = ctypes.util.find_library("X11")
    if name is None:
        return True  # cannot check: let GLFW try
    try:
        x11 = ctypes.CDLL(name)
    except OSError:
        return True
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    handle = x11.XOpenDisplay(display.encode())
    if not handle:
        return False
    x11.XCloseDisplay(handle)
    return True


@contextlib.contextmanager
def _native_stderr_captured():
    """Divert file descriptor 2 (Taichi's C++ messages) into a buffer; yields a list that gets the text."""
    sys.stderr.flush()
    captured: list[str] = []
    saved = os.dup(2)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield captured
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            captured.append(sink.read().decode(errors="replace"))


def open_demo_window(title: str, size: tuple[int, int], fps_limit: int = 60):
    """A visible GGUI window of ``size`` (width, height) pixels; ``UserError`` (one line) if impossible."""
    problem = display_problem()
    if problem:
        raise UserError(f"demo needs a window and {problem}; {FALLBACK}")
    import taichi as ti

    with _native_stderr_captured():
        try:
            return ti.ui.Window(title, tuple(size), vsync=False, show_window=True, fps_limit=fps_limit)
        except Exception as e:  # noqa: BLE001 - GGUI raises a bare RuntimeError without Vulkan
            reason = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
    raise UserError(f"demo needs a Vulkan device and none is usable here ({reason}); {FALLBACK}")
