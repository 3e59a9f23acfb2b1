"""Side-by-side integrator comparison: one scene, one dt, one labelled tile per integrator.

All simulations live in the same Taichi runtime (each ``Simulation`` allocates its own fields)
and are stepped in lockstep, frame by frame; one offscreen window of tile size renders each of
them in turn. A tile whose run diverges freezes on its last good frame, dimmed, and says when.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import overlay
from .outputs import BackgroundWriter, FrameJob, open_image_sinks

GRID_LINE = (24, 26, 30)  # separators between tiles and the colour of unused cells
TARGET_TILE_ASPECT = 4 / 3


def grid_shape(n: int, width: int, height: int) -> tuple[int, int]:
    """(columns, rows) for ``n`` tiles in a ``width`` x ``height`` mosaic.

    Picks the grid whose tiles are largest once penalised for being far from 4:3 (a 16:9 frame:
    2 tiles side by side, 3 or 4 in a 2 x 2 grid, 5 or 6 in 3 x 2).
    """
    best, best_score = (1, n), -1.0
    for cols in range(1, n + 1):
        rows = math.ceil(n / cols)
        w, h = width / cols, height / rows
        aspect = w / h
        score = w * h * min(aspect / TARGET_TILE_ASPECT, TARGET_TILE_ASPECT / aspect)
        if score > best_score + 1e-9:
            best, best_score = (cols, rows), score
    return best


@dataclass
class Tile:
    """One integrator's simulation and what its tile shows."""

    name: str
    sim: object
    view: object
    image: np.ndarray | None = None  # last good frame, unlabelled
    time: float = 0.0  # s, of ``image``
    energy: float = float("nan")  # J, of ``image``: the total energy's change since t = 0
    energy0: float | None = None  # J, total energy at t = 0
    diverged_at: float | None = None


@dataclass
class TileResult:
    """How one integrator's run ended."""

    integrator: str
    diverged_at: float | None
    diverged_step: int | None
    final_time: float
    final_energy: float  # J, the total energy's change since t = 0


class Comparison(FrameJob):
    """Builds one simulation per integrator and writes the mosaic video / frames.

    ``options`` is a ``RenderOptions``: its resolution is the whole mosaic's. ``run`` writes,
    then ``finish()`` (or ``abort()``, see ``FrameJob``).
    """

    def __init__(self, scene, integrators: list[str], options, dt: float | None = None):
        from ..sim.integrators import scene_options
        from ..sim.simulation import Simulation
        from .camera import scene_camera
        from .choose import make_renderer
        from .renderer import SimulationView

        self.scene, self.options = scene, options
        width, height = options.resolution
        self.cols, self.rows = grid_shape(len(integrators), width, height)
        self.tile_w, self.tile_h = width // self.cols, height // self.rows
        self.renderer = make_renderer(self.tile_w, self.tile_h, options.renderer, options.particles or options.springs,
                                      options.quality)
        self.sinks, self.writer = [], None
        try:
            self.tiles = []
            for name in integrators:
                sim = Simulation(scene, integrator=name, dt=dt, options=scene_options(name, scene.data))
                self.tiles.append(Tile(name, sim, SimulationView(sim, options.surface, options.particles, options.springs)))
            self.dt = self.tiles[0].sim.dt
            self.camera = scene_camera(scene.data, self.tile_w / self.tile_h, options.follow)
            info = overlay.run_info(self.tiles[0].sim)
            self.legend = [f"scene: {scene.label}", f"dt = {self.dt:g} s", f"k = {info.stiffness}", f"damping = {info.damping}"]
            self.sinks = open_image_sinks(options.video, options.frames, options.fps, (width, height))
            self.writer = BackgroundWriter(self._compose)
        except BaseException:
            self.abort()
            raise

    def run(self, duration: float, progress=None) -> list[TileResult]:
        """Step every simulation to ``duration`` [s], writing a mosaic per output frame.

        ``progress(frames_done, time)`` is called after each frame.
        """
        from ..sim.simulation import frame_steps, step_count

        total = step_count(duration, self.dt)
        schedule = frame_steps(total, self.options.fps, self.dt)
        for index, target in enumerate(schedule):
            for tile in self.tiles:
                if tile.diverged_at is None:
                    self._advance(tile, target)
            self.writer.submit((index, [(t.name, t.image, t.time, t.energy, t.diverged_at) for t in self.tiles]))
            if progress is not None:
                progress(index + 1, self.tiles[0].sim.time)
        return [TileResult(t.name, t.diverged_at, t.sim.diverged_step, t.sim.time if t.diverged_at is None else t.time,
                           t.energy) for t in self.tiles]

    def _advance(self, tile: Tile, target_step: int):
        sim = tile.sim
        sim.advance(target_step - sim.steps)
        if sim.diverged:
            tile.diverged_at = sim.diverged_at
            return
        m = sim.measure()
        tile.image = self.renderer.render(tile.view, self.camera.following(m["center_of_mass"]))
        if tile.energy0 is None:
            tile.energy0 = m["total_energy"]
        tile.time, tile.energy = sim.time, m["total_energy"] - tile.energy0

    # -- worker thread -----------------------------------------------------------------------
    def _compose(self, item):
        index, tiles = item
        width, height = self.options.resolution
        mosaic = np.empty((height, width, 3), np.uint8)
        mosaic[:] = GRID_LINE
        tw, th = self.tile_w, self.tile_h
        for k, (name, image, time, energy, diverged_at) in enumerate(tiles):
            row, col = divmod(k, self.cols)
            cell = mosaic[row * th:(row + 1) * th, col * tw:(col + 1) * tw]
            cell[:] = image
            subtitle = f"dt = {self.dt:g} s | t = {time:.3f} s | {overlay.ENERGY_LABEL} = {overlay.energy_text(energy)}"
            if diverged_at is not None:
                overlay.dim(cell)
                overlay.draw_banner(cell, f"diverged at t = {diverged_at:.4f} s", size=max(10, th // 12), y=0.45)
                subtitle = f"dt = {self.dt:g} s | frozen at t = {time:.3f} s"
            overlay.draw_title(cell, name, subtitle)
        for k in range(len(tiles), self.cols * self.rows):  # unused cells carry the legend
            row, col = divmod(k, self.cols)
            overlay.draw_info(mosaic[row * th:(row + 1) * th, col * tw:(col + 1) * tw], self.legend,
                              size=max(10, th // 12))
        # Thin separators so tiles read as separate panels.
        for c in range(1, self.cols):
            mosaic[:, c * tw - 1:c * tw + 1] = GRID_LINE
        for r in range(1, self.rows):
            mosaic[r * th - 1:r * th + 1, :] = GRID_LINE
        for sink in self.sinks:
            sink.add(mosaic, index)
