"""GGUI windows, shared by the offscreen renderer and the demo: opening one (hidden or shown), or
saying in one line why it cannot be opened; and reading its image back as a numpy array.

Nothing here imports Taichi at module level (``open_window`` does, when called), so the demo can
probe for a display before Taichi is loaded.
"""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile

import numpy as np

from ..errors import UserError

VULKAN_ADVICE = "install a Vulkan driver (without a GPU: Mesa's lavapipe, package mesa-vulkan-drivers)"


@contextlib.contextmanager
def native_stderr_captured():
    """Divert file descriptor 2 (where Taichi's C++ side prints, e.g. "RHI Error: Can not create
    Vulkan instance") into a buffer; the yielded list receives the text on exit."""
    sys.stderr.flush()
    text: list[str] = []
    saved = os.dup(2)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield text
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text.append(sink.read().decode(errors="replace"))


def last_line(text: str) -> str:
    """The last non-blank line of ``text``, stripped ("" if there is none)."""
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[-1] if lines else ""


class NoVulkanDevice(UserError):
    """GGUI could not open a window: no usable Vulkan device.

    ``error``: the last line of GGUI's exception (or its type name); ``native``: the last line
    Taichi's C++ side printed to stderr meanwhile ("" if none). The message is the renderer's;
    other callers (the demo) word their own from these two.
    """

    def __init__(self, error: str, native: str):
        self.error, self.native = error, native
        reason = "; ".join(r for r in (error, native) if r)
        super().__init__(f"offscreen rendering needs a Vulkan device and none is usable here ({reason}); {VULKAN_ADVICE}")


def open_window(width: int, height: int, title: str = "taichi-soft", visible: bool = False, fps_limit: int = 1000):
    """A GGUI window of ``width`` x ``height`` pixels, hidden unless ``visible``.

    Without a Vulkan device this raises ``NoVulkanDevice`` (a ``UserError``, one line); what
    Taichi's C++ side prints meanwhile is kept out of the terminal. A visible window also needs a
    display: check that first (``demo.display.display_problem``), as GLFW kills the process
    without one.
    """
    import taichi as ti

    with native_stderr_captured() as native:
        try:
            return ti.ui.Window(title, (int(width), int(height)), vsync=False, show_window=visible, fps_limit=fps_limit)
        except Exception as e:  # noqa: BLE001 - GGUI raises a bare RuntimeError for a missing device
            error = e
    raise NoVulkanDevice(last_line(str(error)) or type(error).__name__, last_line(native[0]))


def window_rgb(window) -> np.ndarray:
    """The window's last rendered frame as uint8 RGB [height, width, 3], top row first.

    GGUI hands back float32 [width, height, 4] with the origin at the bottom left. One parallel
    Taichi kernel pass scales, rounds, transposes and flips it: every frame is read back, and one
    parallel pass replaces numpy's chain of transposed copies (clip, scale, cast).
    """
    from .readback import float_image_to_rgb8  # imports Taichi: not at this module's load

    buf = window.get_image_buffer_as_numpy()
    width, height = buf.shape[:2]
    rgb = np.empty((height, width, 3), np.uint8)
    float_image_to_rgb8(np.ascontiguousarray(buf, dtype=np.float32), rgb)
    return rgb
