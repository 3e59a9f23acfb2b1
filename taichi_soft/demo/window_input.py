"""The demo window's keys and left mouse button, as the ``WindowInput`` mixin of ``DemoApp``: each
key press applied through ``DemoController`` (or the app: camera, screenshot, recording, what is
drawn), the button handed to ``mouse.MouseHand`` over the scene (the panel takes it over itself).
"""
from __future__ import annotations

import taichi as ti

from .panel import DRAW_KEYS, PANEL_X


class WindowInput:
    """Keys and the left mouse button of a ``DemoApp``, read once per frame (``_handle_input``)."""

    def _handle_input(self):
        """Keys and the left mouse button since the last frame, then the drag to the cursor."""
        w = self.window
        # Two queries (GGUI's events carry no press/release flag): a press and its release within
        # one frame act in that order, a quick click (a poke).
        presses, releases = w.get_events(ti.ui.PRESS), w.get_events(ti.ui.RELEASE)
        for e in presses:
            self._press(e.key)
        # Shift is tracked from its own events: GGUI's is_pressed(SHIFT) was seen stuck down after
        # a Shift+click under XTest, turning the next plain click into a pin.
        if any(e.key == ti.ui.SHIFT for e in releases):
            self._shift = False
        if self.hand.held is not None and self.ctl.grab.held is None:
            self.hand.cancel()  # R or a switch let go of the grab: the release must not poke
        if any(e.key == ti.ui.LMB for e in releases):
            self.hand.release()
        if self.hand.held is not None:
            self.hand.motion(w.get_cursor_pos(), self.cam_spec)

    def _press(self, key):
        if key == ti.ui.SHIFT:
            self._shift = True
        elif key == ti.ui.LMB:
            cursor = self.window.get_cursor_pos()
            # The panel's ImGui widgets take clicks over it; the scene the rest.
            if cursor[0] < PANEL_X and self.cam_spec is not None and not self.ctl.message:
                self.hand.press(cursor, self.cam_spec, shift=self._shift)
            return
        if key == ti.ui.ESCAPE:
            self.window.running = False
        elif key == ti.ui.SPACE:
            self.ctl.toggle_pause()
        elif key == "n":
            self.ctl.single_step()
        elif key == "r":
            self.ctl.restart()
        elif key == "m":
            self.ctl.set_slow_motion(0.25 if self.ctl.settings.slow_motion == 1.0 else 1.0)
        elif key == "c":
            self.reset_camera()
        elif key == "p":
            self.screenshot()  # saved at the end of this frame
        elif key == "v":
            self.toggle_recording()
        elif key in DRAW_KEYS:
            self.draw[DRAW_KEYS[key]] = not self.draw[DRAW_KEYS[key]]
        elif key == "x":
            self.ctl.clear_pins()
        elif key == "i":
            self.hand.pin_mode = not self.hand.pin_mode
        elif key == "t":
            self.show_timing = not self.show_timing
