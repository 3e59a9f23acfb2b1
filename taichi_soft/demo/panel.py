"""The demo's ImGui control panel (the right 30 % of the window, two columns: run and view,
physics), as the ``ControlPanel`` mixin of ``DemoApp``: buttons, checkboxes and sliders, each
applied through ``DemoController``; and ``ladder``, how the dt and stiffness buttons step.
"""
from __future__ import annotations

import math

from ..sim.lattice import SPRING_KINDS

PANEL_X, PANEL_W = 0.7, 0.3  # ImGui control panel: right 30 % of the window, in two columns
# Letter keys only: Taichi 1.7.4's window never delivers digit or function keys (taichi #5277).
# W A S D Q E move the camera (``track_user_inputs``), so they are not used here.
DRAW_KEYS = {"f": "surface", "o": "particles", "j": "stretch", "k": "shear", "l": "bend"}
DT_RANGE = (1e-5, 5e-2)  # s: what the dt buttons may reach
K_RANGE = (1.0, 1e7)  # N/m: what the stiffness buttons may reach
GRAB_K_RANGE = (10.0, 1e6)  # N/m: the grab stiffness buttons (1e6: explicit methods blow up at dt = 2 ms)
POKE_RANGE = (0.0, 20.0)  # m/s: the poke slider


def _changed(new: float, old: float) -> bool:
    """ImGui sliders hand back float32: ignore round-off so an untouched slider sets nothing."""
    return abs(new - old) > 1e-6 * max(1.0, abs(old))


def ladder(value: float, direction: int) -> float:
    """The next value above (``direction`` = +1) or below (-1) ``value`` on the 1-2-5 ladder
    (..., 0.5, 1, 2, 5, 10, ...): how the demo's dt and stiffness buttons step, in physical units."""
    exponent = math.floor(math.log10(value))
    steps = [m * 10.0**e for e in (exponent - 1, exponent, exponent + 1) for m in (1.0, 2.0, 5.0)]
    steps = [float(f"{v:.3g}") for v in steps]
    if direction > 0:
        return min(v for v in steps if v > value * (1 + 1e-9))
    return max(v for v in steps if v < value * (1 - 1e-9))



class ControlPanel:
    """The control panel of a ``DemoApp``: ``_draw_panel`` draws it and applies what was clicked."""

    def _choices(self, g, title: str, options: list[str], current: str) -> str | None:
        """One button per option under ``title``, the current one marked "> name <"; returns
        the option clicked if it is not the current one."""
        g.text(title)
        picked = None
        for name in options:
            if g.button((f"> {name} <" if name == current else name) + f"###{title}{name}") and name != current:
                picked = name
        return picked

    def _ladder_buttons(self, g, label: str, value: float, bounds, apply, unit: str):
        """Two buttons that step ``value`` down / up the 1-2-5 ladder, each showing the value it sets."""
        lower, higher = ladder(value, -1), ladder(value, +1)
        if lower >= bounds[0] and g.button(f"{label} -> {lower:g} {unit}###{label}-"):
            self._guard(apply, lower)
        if higher <= bounds[1] and g.button(f"{label} -> {higher:g} {unit}###{label}+"):
            self._guard(apply, higher)

    def _draw_panel(self):
        ctl, s, g = self.ctl, self.ctl.settings, self.gui
        column = PANEL_W / 2
        with g.sub_window("Run and view", PANEL_X, 0.0, column, 1.0):
            if g.button("Pause (Space)" if not s.paused else "Play (Space)"):
                ctl.toggle_pause()
            if g.button("Single step (N)"):
                ctl.single_step()
            if g.button("Reset, paused (R)"):
                ctl.restart()
            slow = g.checkbox("Slow motion (M)", s.slow_motion < 1.0)
            if slow != (s.slow_motion < 1.0):
                ctl.set_slow_motion(0.25 if slow else 1.0)
            if s.slow_motion < 1.0:
                f = g.slider_float("x###slow", s.slow_motion, 0.02, 0.99)
                if _changed(f, s.slow_motion):
                    ctl.set_slow_motion(f)
            picked = self._choices(g, "Integrator:", ctl.integrator_names(), s.integrator)
            if picked:  # the first switch to an integrator compiles it (seconds)
                self._guard(ctl.set_integrator, picked)
            picked = self._choices(g, "Terrain:", ctl.terrain_kinds(), s.terrain)
            if picked:
                self._guard(ctl.set_terrain, picked)
                self._sync_view()
            g.text("Draw:")
            for key, name in DRAW_KEYS.items():
                self.draw[name] = g.checkbox(f"{name} ({key.upper()})", self.draw[name])
            self.follow = g.checkbox("camera follows", self.follow)
            if g.button("Reset camera (C)"):
                self.reset_camera()
            if g.button("Screenshot (P)"):
                self.screenshot()
            if g.button("Stop recording (V)" if self.recording else "Record MP4 (V)"):
                self.toggle_recording()
        with g.sub_window("Physics", PANEL_X + column, 0.0, column, 1.0):
            g.text(f"time step dt = {s.dt:g} s")
            self._ladder_buttons(g, "dt", s.dt, DT_RANGE, ctl.set_dt, "s")
            for kind in SPRING_KINDS:
                g.text(f"k {kind} = {s.stiffness[kind]:g} N/m")
                self._ladder_buttons(g, f"k {kind}", s.stiffness[kind], K_RANGE,
                                     lambda k, kind=kind: ctl.set_stiffness(kind, k), "N/m")
            self._slider(g, "damping [N s/m]", "damping", s.damping, 0.0, 200.0, ctl.set_damping)
            self._slider(g, "restitution", "rest", s.restitution, 0.0, 1.0, lambda v: ctl.set_contact(restitution=v))
            self._slider(g, "friction coefficient", "fric", s.friction, 0.0, 1.5, lambda v: ctl.set_contact(friction=v))
            self._slider(g, "particle mass [kg]", "mass", s.particle_mass, 0.05, 10.0, ctl.set_particle_mass)
            self._slider(g, "gravity [m/s^2]", "g", s.gravity, 0.0, 30.0, ctl.set_gravity)
            g.text("Mouse (left button on the body):")
            g.text(f"grab k = {s.grab_stiffness:g} N/m")
            self._ladder_buttons(g, "grab k", s.grab_stiffness, GRAB_K_RANGE, ctl.set_grab_stiffness, "N/m")
            self._slider(g, "poke speed [m/s]", "poke", s.poke_speed, *POKE_RANGE, ctl.set_poke_speed)
            self.hand.pin_mode = g.checkbox("pin mode (I)", self.hand.pin_mode)
            if g.button(f"Clear {len(ctl.pins)} pins (X)###clearpins"):
                ctl.clear_pins()
            g.text("Start pose (used at reset):")
            self._slider(g, "drop height [m]", "height", s.height, -2.0, 30.0, lambda v: ctl.set_pose(height=v))
            self._slider(g, "rotation [deg]", "rot", s.rotation, -90.0, 90.0, lambda v: ctl.set_pose(rotation=v))

    def _slider(self, g, title, key, value, lo, hi, apply):
        """``title`` on its own line (a narrow column clips labels beside a slider), then a slider
        over the physical value itself."""
        g.text(title)
        new = g.slider_float(f"##{key}", value, lo, hi)
        if _changed(new, value):
            self._guard(apply, float(new))

    def _guard(self, action, *args):
        """Run a control's action; an error (e.g. a solver refusing a value) is shown, never raised."""
        try:
            action(*args)
        except Exception as e:  # noqa: BLE001 - the window must not crash on a control
            self.notice = f"{type(e).__name__}: {e}".splitlines()[0]
