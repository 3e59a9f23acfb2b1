"""Recording one run: render each output frame, overlay it, hand it to the writers.

``FrameRecorder`` is what ``python main.py run --video/--frames/--export-mesh`` passes to
``Simulation.run(on_frame=...)``. The main thread steps and renders (GGUI must stay on the
thread that opened it); overlays, PNG and ffmpeg encoding and mesh files run on a worker thread
behind a bounded queue.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from . import overlay
from .outputs import BackgroundWriter, FrameJob, open_image_sinks

HOLD_SECONDS = 1.0  # how long a diverged run's last frame stays on screen with the banner


@dataclass
class RenderOptions:
    """What to write and how to draw it. Paths are validated by the CLI before any simulation."""

    video: Path | None = None
    frames: Path | None = None
    mesh_dir: Path | None = None
    mesh_format: str = "ply"
    usd: Path | None = None  # --export-usd (caches.UsdCache)
    pc2_dir: Path | None = None  # --export-pc2 (caches.Pc2Cache)
    fps: float = 30.0  # output frames per simulated second
    resolution: tuple = (1280, 720)  # (width, height) pixels
    surface: bool = True
    particles: bool = False
    springs: bool = False
    follow: bool | None = None  # None: the terrain's default
    overlay: bool = True
    renderer: str = "auto"  # "auto", "ggui" or "taichi" (render.choose)
    quality: str = "high"  # the taichi renderer's look: render.quality.QUALITIES
    pipeline: str = "serial"  # "serial" or "overlap" (render.pipeline): where the frames are drawn
    legend: tuple = ()  # further overlay lines under the run's labels (e.g. its error estimate)

    @property
    def needs_renderer(self) -> bool:
        return self.video is not None or self.frames is not None

    @property
    def any(self) -> bool:
        return self.needs_renderer or self.needs_meshes

    @property
    def needs_meshes(self) -> bool:
        """Whether the bodies' surfaces are read back each frame (mesh files, animation caches)."""
        return self.mesh_dir is not None or self.usd is not None or self.pc2_dir is not None


class FrameVisits:
    """``on_frame(sim)`` of both pipelines: a diverged state is only noted (its NaN or runaway
    values are not worth drawing); any other gets its labels (``FrameLabels``) and goes to
    ``hand_over(sim, lines, camera)``, which counts ``frames``; then ``progress(frames, sim)``."""

    labels = progress = None
    frames = 0
    diverged_at: float | None = None

    def __call__(self, sim):
        if sim.diverged:
            self.diverged_at = sim.diverged_at
            return
        lines, cam = self.labels.describe(sim)
        self.hand_over(sim, lines, cam)
        if self.progress is not None:
            self.progress(self.frames, sim)

    def hand_over(self, sim, lines, cam):
        raise NotImplementedError


class FrameRecorder(FrameJob, FrameVisits):
    """Callable ``on_frame(sim)`` for ``Simulation.run``; then ``finish()`` or ``abort()``.

    Opening it opens the offscreen window, so a machine without Vulkan fails here, in one line
    (``UserError``), before any simulation. ``progress(frames_done, sim)`` is called per frame.
    """

    def __init__(self, sim, options: RenderOptions, progress=None):
        from .embedded import body_surface

        self.sim, self.options, self.progress = sim, options, progress
        width, height = options.resolution
        self.renderer = self.view = self.writer = None
        self.image_sinks, self.mesh_sinks = [], []
        if options.needs_renderer:
            from .choose import make_renderer
            from .renderer import SimulationView

            self.renderer = make_renderer(width, height, options.renderer, options.particles or options.springs,
                                          options.quality)
        try:
            if self.renderer is not None:
                self.view = SimulationView(sim, options.surface, options.particles, options.springs)
            self.surface = self.view.surface if self.view else body_surface(sim.model)
            self.labels = FrameLabels(sim, options)
            self.image_sinks = open_image_sinks(options.video, options.frames, options.fps, (width, height))
            if options.mesh_dir:
                from .export import MeshFrames

                self.mesh_sinks.append(MeshFrames(options.mesh_dir, options.mesh_format, self.surface))
            if options.usd:
                from .caches import UsdCache
                from .meshes import terrain_meshes

                terrain = sim.terrain
                self.mesh_sinks.append(UsdCache(options.usd, self.surface,
                                                terrain_meshes(terrain.kind, terrain.params(), sim.scene.data), options.fps))
            if options.pc2_dir:
                from .caches import Pc2Cache

                self.mesh_sinks.append(Pc2Cache(options.pc2_dir, self.surface))
            self.writer = BackgroundWriter(self._write)
        except BaseException:
            self.abort()
            raise
        self.frames = 0
        self.last = None  # (image, overlay lines) of the last good frame
        self.diverged_at: float | None = None

    # -- main thread -------------------------------------------------------------------------
    def hand_over(self, sim, lines, cam):
        self.draw(lines, cam, sim.time)

    def draw(self, lines: list[str], cam, time: float):
        """Render the simulation's current positions seen by ``cam`` (a ``CameraSpec``) and hand
        the frame (and the surface mesh, if written) to the writer thread with the overlay
        ``lines``; ``time`` [s] is the frame's simulated time."""
        image = mesh = None
        if self.renderer is not None:
            image = self.renderer.render(self.view, cam)
        else:
            self.surface.update(self.sim.state.x)
        if self.options.needs_meshes:
            mesh = self.surface.numpy()
        self.writer.submit((self.frames, image, lines, None, mesh, time))
        self.last = (image, lines)
        self.frames += 1

    def output_sinks(self) -> list:
        return self.image_sinks + self.mesh_sinks

    def finish(self) -> list[Path]:
        """Close the outputs (after the diverged hold, if any); returns the paths written."""
        if self.diverged_at is not None and self.last is not None and self.renderer is not None:
            try:
                image, lines = self.last
                banner = f"DIVERGED at t = {self.diverged_at:.4f} s"
                for _ in range(max(1, round(HOLD_SECONDS * self.options.fps))):
                    self.writer.submit((self.frames, image, lines, banner, None, self.diverged_at))
                    self.frames += 1
            except BaseException:
                self.abort()
                raise
        return super().finish()

    # -- worker thread -----------------------------------------------------------------------
    def _write(self, item):
        index, image, lines, banner, mesh, time = item
        if image is not None:
            image = image.copy()  # the main thread keeps the clean last frame for the hold
            if self.options.overlay:
                overlay.draw_info(image, lines)
            if banner:
                overlay.draw_banner(image, banner)
            for sink in self.image_sinks:
                sink.add(image, index)
        if mesh is not None:
            for sink in self.mesh_sinks:
                sink.add(mesh, index, time)


class FrameLabels:
    """What a frame says and where its camera looks, from the simulation's state (the overlay's
    lines and the ``CameraSpec``): computed where the simulation runs, so the render process of
    ``--pipeline overlap`` gets them ready-made with the positions."""

    def __init__(self, sim, options: RenderOptions):
        from .camera import scene_camera

        width, height = options.resolution
        self.info = overlay.run_info(sim, options.legend)
        self.camera = scene_camera(sim.scene.data, width / height, options.follow,
                                   overlay.info_margin(overlay.INFO_LINES + len(options.legend)) if options.overlay else 0.0)
        self.energy0: float | None = None  # total energy [J] at the first frame, the overlay's zero

    def describe(self, sim) -> tuple[list[str], object]:
        """(overlay lines, camera) of ``sim``'s current state; the first call sets the energy's zero."""
        m = sim.measure()
        if self.energy0 is None:  # the first frame is the start (t = 0)
            self.energy0 = m["total_energy"]
        return self.info.lines(sim.time, m["total_energy"] - self.energy0), self.camera.following(m["center_of_mass"])


def frame_count(duration: float, dt: float, fps: float) -> int:
    """Frames ``Simulation.run`` visits for ``duration`` [s] at ``dt`` [s] and ``fps``."""
    from ..sim.simulation import frame_steps, step_count

    return len(frame_steps(step_count(duration, dt), fps, dt))

