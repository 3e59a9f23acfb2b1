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

from ..sim.lattice import SPRING_KINDS
from ..render.camera import CameraSpec, scene_camera
from ..render.renderer import SimulationView, aim_camera, apply_camera, draw_view
from . import hud
from .canvas2d import Batch2D
from .capture import Recording, default_path
from .controller import DemoController
from .display import open_demo_window
from .frametimer import FrameTimer
from .marks import Marks
from .mouse import MouseHand
from .pacing import Pacer
from .panel import PANEL_W, PANEL_X, ControlPanel
from .window_input import WindowInput

OVERLAY_VERTICES = 400_000  # capacity of the HUD triangle buffer (text is ~10k per line)
HUD_MARGIN = 0.2  # fraction of the height the HUD text covers at the top (default camera keeps clear)


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


class DemoApp(ControlPanel, WindowInput):
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
        draw_view(self.canvas, self.scene, v, self.size)

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
