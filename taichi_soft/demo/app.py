"""The demo window: the scene as the renderer draws it, ImGui controls, keys and the HUD.

One frame: read keys and the mouse (``mouse.MouseHand``: grab, drag, poke, pin), take the steps
the ``Pacer`` allows, pull the state onto the draw fields, draw terrain, body, springs and markers
(pins, the grab), overlay the HUD (large outlined text and the energy plot, ``hud``) and the ImGui
control panel, show. Everything the controls change goes through ``DemoController``; nothing here
touches physics directly. ``frametimer.FrameTimer`` times each part of the frame (T shows it).
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import taichi as ti

from ..lattice import SPRING_KINDS
from ..render.camera import CameraSpec, scene_camera
from ..render.renderer import SimulationView, aim_camera, apply_camera, draw_view
from . import hud
from .canvas2d import Batch2D
from .capture import Recording, default_path
from .controller import DemoController, ladder
from .display import open_demo_window
from .frametimer import FrameTimer
from .marks import Marks
from .mouse import MouseHand
from .pacing import Pacer

PANEL_X, PANEL_W = 0.7, 0.3  # ImGui control panel: right 30 % of the window, in two columns
OVERLAY_VERTICES = 400_000  # capacity of the HUD triangle buffer (text is ~10k per line)
HUD_MARGIN = 0.2  # fraction of the height the HUD text covers at the top (default camera keeps clear)
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


def _left_of_panel(spec: CameraSpec, aspect: float) -> CameraSpec:
    """The camera slid sideways so the action it framed is centred left of the control panel.

    Moving eye and target by d along the camera's right moves the image by d / (depth tan(half
    width angle)) half-widths; the panel covers ``PANEL_W`` of the width, so slide by half of it.
    """
    eye, target = np.asarray(spec.position, float), np.asarray(spec.lookat, float)
    distance = np.linalg.norm(eye - target)
    half_w = np.tan(np.radians(spec.fov) / 2) * aspect * distance
    shift = PANEL_W * half_w * spec.right()
    return replace(spec, position=tuple(eye + shift), lookat=tuple(target + shift))


class DemoApp:
    """``DemoApp(controller, (width, height)).run()`` opens the window and runs until closed."""

    def __init__(self, controller: DemoController, size=(1280, 800), window=None):
        self.ctl = controller
        self.size = tuple(size)
        self.window = window or open_demo_window("taichi-soft demo", self.size)
        self.canvas = self.window.get_canvas()
        self.scene = self.window.get_scene()
        self.gui = self.window.get_gui()
        self.camera = ti.ui.Camera()
        self.pacer = Pacer()
        self.draw = {"surface": True, "particles": False, "stretch": False, "shear": False, "bend": False}
        self.follow = False
        self.notice: str | None = None  # last screenshot / recording message
        self._shot_request = None  # screenshot asked for this frame (True or a path): saved once drawn
        self.recording: Recording | None = None
        self.stats: dict = {}
        self.hand = MouseHand(controller, self.size)
        self.marks = Marks()
        self.timer = FrameTimer(sync=ti.sync)
        self.show_timing = False  # T: the frame timer's line in the HUD
        self._shift = False  # Shift held (from its press and release events)
        self.cam_spec: CameraSpec | None = None  # the camera of the frame on screen (picking uses it)
        self.session = None  # a ``session.SessionRecorder`` when recording inputs (--record)
        self._generation = None
        self._overlay_v = ti.Vector.field(2, ti.f32, OVERLAY_VERTICES)
        self._overlay_c = ti.Vector.field(3, ti.f32, OVERLAY_VERTICES)
        self._sync_view()

    # -- scene and camera -------------------------------------------------------------------
    def _sync_view(self):
        """(Re)build the draw fields and the default camera after the simulation was replaced."""
        if self._generation == self.ctl.generation:
            return
        self._generation = self.ctl.generation
        self.view = SimulationView(self.ctl.sim, surface=True, particles=True, springs=True)
        self.hand.cancel()
        self.hand.warm()
        self.reset_camera()

    def _default_camera(self) -> CameraSpec:
        """The scene's default camera for this window, shifted left of the control panel."""
        aspect = self.size[0] / self.size[1]
        return _left_of_panel(scene_camera(self.ctl.sim.scene.data, aspect, top_margin=HUD_MARGIN), aspect)

    def reset_camera(self):
        """Back to the scene's default camera (tracking the bodies where the default does)."""
        spec = self._default_camera()
        self.follow = spec.follow
        self._fov = spec.fov
        self._distance = float(np.linalg.norm(np.subtract(spec.position, spec.lookat)))
        self._com = None
        self.cam_spec = spec
        aim_camera(self.camera, spec)

    def _update_camera(self, com):
        c = self.camera
        # Right-drag turns the view, WASD/QE move; steps scale with how far away the scene is.
        c.track_user_inputs(self.window, movement_speed=self._distance / 150, hold_key=ti.ui.RMB)
        if self.follow and com is not None and np.all(np.isfinite(com)):
            if self._com is not None:
                delta = np.asarray(com) - self._com
                c.position(*(c.curr_position.to_numpy() + delta))
                c.lookat(*(c.curr_lookat.to_numpy() + delta))
            self._com = np.asarray(com, dtype=np.float64)
        eye = c.curr_position.to_numpy()
        front = c.curr_lookat.to_numpy() - eye
        front /= max(np.linalg.norm(front), 1e-12)
        # track_user_inputs keeps the look-at point 1 m ahead; the lights are placed from the
        # camera-to-target distance, so aim at the original distance to keep the lighting fixed.
        spec = CameraSpec(tuple(eye), tuple(eye + self._distance * front), tuple(c.curr_up.to_numpy()), self._fov)
        self.cam_spec = spec
        apply_camera(self.scene, c, spec)  # the renderer's camera and lights

    # -- one frame --------------------------------------------------------------------------
    def frame(self):
        timer = self.timer
        with timer.part("input"):
            self._handle_input()
            self._sync_view()
        ctl = self.ctl
        s = ctl.settings
        stepped = 0
        with timer.part("simulation"):
            if s.paused or ctl.message:
                self.pacer.pause()
            else:
                n = self.pacer.plan(ctl.sim.dt, s.slow_motion)
                start = time.perf_counter()
                stepped = ctl.step(n)
                self.pacer.record(stepped, time.perf_counter() - start, ctl.sim.dt)
        with timer.part("read-back"):
            measures = ctl.sample()
            if stepped:
                self.stats = ctl.solver_stats()  # iteration counts of the steps just taken
            if not ctl.message:
                self.view.update()  # after a divergence the last good shape stays on screen
                self.marks.update(ctl)
        with timer.part("draw"):
            self._update_camera(measures["center_of_mass"] if measures else None)
            self._draw_scene()
            self._draw_hud()
            self._draw_panel()
        # A screenshot is saved only now that everything is drawn: saving draws the frame (GGUI
        # ends the ImGui frame there), so saving while keys are read gives a blank image and
        # saving from a button, inside the panel's ImGui window, crashed Taichi.
        if self._shot_request is not None:
            request, self._shot_request = self._shot_request, None
            self._save_screenshot(None if request is True else request)
        if self.recording is not None:
            self.recording.add(self.window)

    def show(self):
        """Show the frame drawn (GGUI renders it now) and close the frame timer's frame."""
        if self.session is not None:
            self.session.end_frame(self)
        with self.timer.part("show"):
            self.window.show()
        self.timer.end_frame()

    def replay_frame(self, camera):
        """Draw a frame of a replayed session (``replay.replay``): the state its inputs left, seen
        by the recorded ``camera`` = [eye, lookat, up, fov]."""
        self._sync_view()
        ctl = self.ctl
        ctl.sample()
        self.stats = ctl.solver_stats() or self.stats
        if not ctl.message:
            self.view.update()
            self.marks.update(ctl)
        eye, lookat, up, fov = camera
        self.cam_spec = CameraSpec(tuple(eye), tuple(lookat), tuple(up), float(fov))
        apply_camera(self.scene, self.camera, self.cam_spec)
        self._draw_scene()
        self._draw_hud()
        self._draw_panel()

    def _draw_scene(self):
        v = self.view
        v.show_surface, v.show_particles = self.draw["surface"], self.draw["particles"]
        v.show_springs = {kind for kind in SPRING_KINDS if self.draw[kind]}
        self.marks.draw(self.scene, 2.5 * v.particle_radius)  # queued before draw_view renders the scene
        draw_view(self.canvas, self.scene, v)

    def _draw_hud(self):
        batch = Batch2D(self.size)
        notice = self.notice
        if self.recording is not None:
            notice = f"recording {self.recording.path} (V stops)"
        extra = [self.timer.text()] if self.show_timing else []
        hud.draw_hud(batch, self.ctl, self.pacer, self.stats, notice, width=round(PANEL_X * self.size[0]),
                     hand=hud.hand_text(self.ctl, self.hand), extra=extra)
        verts, colors = batch.triangles()
        n = min(len(verts), OVERLAY_VERTICES) // 3 * 3
        # Unused vertices sit off-canvas: their triangles are clipped away.
        buf_v = np.full((OVERLAY_VERTICES, 2), -2.0, np.float32)
        buf_c = np.zeros((OVERLAY_VERTICES, 3), np.float32)
        buf_v[:n], buf_c[:n] = verts[:n], colors[:n]
        self._overlay_v.from_numpy(buf_v)
        self._overlay_c.from_numpy(buf_c)
        self.canvas.triangles(self._overlay_v, per_vertex_color=self._overlay_c)

    # -- controls ---------------------------------------------------------------------------
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

    # -- capture ----------------------------------------------------------------------------
    def screenshot(self, path=None):
        """Ask for a PNG of the window (ImGui included), by default under out/; it is saved at
        the end of the current frame, once everything is drawn."""
        self._shot_request = path or True

    def _save_screenshot(self, path=None):
        path = path or default_path("shot", self.ctl.sim.scene.name, ".png")
        try:
            self.window.save_image(str(path))
            self.notice = f"saved {path}"
        except Exception as e:  # noqa: BLE001 - a full disk must not end the lesson
            self.notice = f"screenshot failed: {e}".splitlines()[0]
        return path

    def toggle_recording(self):
        try:
            if self.recording is None:
                self.recording = Recording(default_path("rec", self.ctl.sim.scene.name, ".mp4"), self.size)
            else:
                path = self.recording.stop()
                self.recording = None
                self.notice = f"saved {path}"
        except Exception as e:  # noqa: BLE001 - no ffmpeg, disk full: say so, keep running
            self.recording = None
            self.notice = f"recording failed: {e}".splitlines()[0]

    # -- main loop --------------------------------------------------------------------------
    def run(self, frames: int | None = None, screenshot=None) -> None:
        """Run until the window closes, or for ``frames`` frames; then save ``screenshot`` if given."""
        done = 0
        try:
            while self.window.running and (frames is None or done < frames):
                if screenshot is not None and frames is not None and done == frames - 1:
                    self.screenshot(screenshot)  # saved at the end of the last frame
                self.frame()
                done += 1
                self.show()
        finally:
            if self.recording is not None:
                self.toggle_recording()
            self.close_session()
            self.window.destroy()

    def close_session(self):
        """Write the recorded session (--record), if one is being recorded; says where on stdout."""
        if self.session is not None:
            session, self.session = self.session, None
            self.ctl.recorder = None
            path = session.close(self.ctl)
            print(f"demo: session of {len(session.frames)} frames saved to {path}")


def run_demo(scene="plane", overrides=(), integrator=None, dt=None, size=(1280, 800), frames=None, screenshot=None,
             paused=False, duration=None, record=None):
    """Open the window, build the simulation and run (Taichi must be initialised); ``paused``:
    start paused (Space plays); ``duration`` [s]: stop the simulation there (None: run on);
    ``record``: save the session's inputs to this JSON file at the end (``session``).

    The window comes first: without a display or Vulkan that fails in one line before seconds
    of kernel compilation.
    """
    window = open_demo_window("taichi-soft demo", size)
    ctl = DemoController(scene, overrides, integrator, dt, paused=paused, duration=duration)
    app = DemoApp(ctl, size, window)
    if record is not None:
        start_session(app, record)
    app.run(frames, screenshot)


def start_session(app: DemoApp, path):
    """Record ``app``'s inputs from now on into the session file ``path`` (written when it closes)."""
    from .. import runtime
    from .session import SessionRecorder

    ctl = app.ctl
    setup = {"scene": ctl.scene_name, "overrides": list(ctl.overrides), "integrator": ctl.settings.integrator,
             "dt": ctl.settings.dt, "paused": ctl.settings.paused, "duration": ctl.settings.duration,
             "resolution": list(app.size),
             **{k: v for k, v in (runtime.current() or {}).items() if k in ("arch", "precision", "fast_math")}}
    app.session = SessionRecorder(path, setup)
    ctl.recorder = app.session
