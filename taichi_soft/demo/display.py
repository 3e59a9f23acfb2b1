"""Opening the demo's visible window, or saying in one line why it cannot be opened.

Two things can be missing: a display (GLFW then aborts the whole process with "cannot initialize
GLFW", so it is probed first, without GLFW) and a Vulkan device (GGUI raises a RuntimeError and
its C++ side prints more lines to stderr, which are kept out of the terminal: both handled by
``render.window.open_window``, which the offscreen renderer uses too).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
from pathlib import Path

from ..errors import UserError
from ..render.window import NoVulkanDevice, open_window

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


def open_demo_window(title: str, size: tuple[int, int], fps_limit: int = 60):
    """A visible GGUI window of ``size`` (width, height) pixels; ``UserError`` (one line) if impossible."""
    problem = display_problem()
    if problem:
        raise UserError(f"demo needs a window and {problem}; {FALLBACK}")
    try:
        return open_window(size[0], size[1], title, visible=True, fps_limit=fps_limit)
    except NoVulkanDevice as e:
        raise UserError(f"demo needs a Vulkan device and none is usable here ({e.error}); {FALLBACK}") from None
