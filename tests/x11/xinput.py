"""Real keyboard and mouse input for an X display, through the XTest extension (libXtst).

Used to drive the demo window as a teacher would (``tests.x11.scripted``): the events go through the
X server, GLFW and GGUI exactly as a keyboard's would, so a key the window does not deliver
fails there too. Plain ctypes; needs libX11 and libXtst (present wherever Xvfb is).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os

# X keysym names of the keys the demo uses that are not their own name.
KEYSYMS = {" ": "space", "Escape": "Escape", "Shift": "Shift_L"}
BUTTONS = {"LMB": 1, "MMB": 2, "RMB": 3}


class XInput:
    """Fake input events on the X display ``display`` (default: $DISPLAY)."""

    def __init__(self, display: str | None = None):
        display = display or os.environ.get("DISPLAY", "")
        names = {lib: ctypes.util.find_library(lib) for lib in ("X11", "Xtst")}
        missing = [lib for lib, name in names.items() if name is None]
        if missing:
            raise OSError(f"lib{' and lib'.join(missing)} not found (install libx11-6 libxtst6)")
        self.x11, self.xtst = ctypes.CDLL(names["X11"]), ctypes.CDLL(names["Xtst"])
        self.x11.XOpenDisplay.restype = ctypes.c_void_p
        self.x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
        self.x11.XStringToKeysym.restype = ctypes.c_ulong
        self.x11.XStringToKeysym.argtypes = [ctypes.c_char_p]
        self.x11.XKeysymToKeycode.restype = ctypes.c_ubyte
        self.x11.XKeysymToKeycode.argtypes = [ctypes.c_void_p, ctypes.c_ulong]
        self.x11.XFlush.argtypes = [ctypes.c_void_p]
        self.x11.XSync.argtypes = [ctypes.c_void_p, ctypes.c_int]
        self.x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
        self.xtst.XTestFakeKeyEvent.argtypes = [ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_ulong]
        self.xtst.XTestFakeButtonEvent.argtypes = [ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_ulong]
        self.xtst.XTestFakeMotionEvent.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                                   ctypes.c_ulong]
        self.dpy = self.x11.XOpenDisplay(display.encode())
        if not self.dpy:
            raise OSError(f"cannot open X display {display!r}")

    def _sync(self):
        self.x11.XSync(self.dpy, 0)

    def keycode(self, key: str) -> int:
        """The keycode of a key named as GGUI names it ("a", " ", "Escape", ...)."""
        code = self.x11.XKeysymToKeycode(self.dpy, self.x11.XStringToKeysym(KEYSYMS.get(key, key).encode()))
        if not code:
            raise ValueError(f"no keycode for key {key!r}")
        return code

    def key(self, key: str, down: bool):
        self.xtst.XTestFakeKeyEvent(self.dpy, self.keycode(key), int(down), 0)
        self._sync()

    def move(self, x: int, y: int):
        """Pointer to pixel (x, y) of the screen (the window sits at the top-left corner)."""
        self.xtst.XTestFakeMotionEvent(self.dpy, -1, int(x), int(y), 0)
        self._sync()

    def button(self, name: str, down: bool):
        self.xtst.XTestFakeButtonEvent(self.dpy, BUTTONS[name], int(down), 0)
        self._sync()

    def close(self):
        if self.dpy:
            self.x11.XCloseDisplay(self.dpy)
            self.dpy = None
