"""The offscreen renderer without Vulkan: a ``SimulationView`` drawn by the Taichi rasterizer.

``TaichiRenderer.render(view, camera)`` returns the frame as uint8 RGB [height, width, 3], as
``renderer.Renderer`` (GGUI) does, for surfaces and terrain (particles and springs need GGUI),
with the key light's shadows and anti-aliasing by ``--quality`` (``quality.py``, ``shadows.py``;
docs/rendering.md, "Shadows and anti-aliasing").
"""
import numpy as np
import taichi as ti

from .camera import CameraSpec, projection_matrix, view_matrix
from .lighting import light_rig
from .renderer import BACKGROUND, SimulationView


class _TerrainImage:
    """A view's terrain as a ``TaichiRenderer`` last drew it: keys (depth, colour, key-light share)
    in ``raster``, supersampled colours in ``color`` (or None), ``drawn`` = (terrain_version,
    camera) it was drawn for."""

    def __init__(self, view, raster):
        self.view, self.raster, self.color, self.drawn = view, raster, None, None


class TaichiRenderer:
    """The offscreen renderer without Vulkan: ``raster.TaichiRasterizer`` draws the views' lit
    meshes in Taichi kernels (the CPU path; see ``choose_renderer``). Same ``render`` as
    ``Renderer``; surfaces and terrain only (particles and springs need GGUI).

    ``quality`` (``quality.QUALITIES``): ``low`` draws what GGUI draws (the checker filtered for its
    footprint, no shadows, one sample a pixel); ``medium`` adds the bodies' shadows from the key
    light (``shadows.py``); ``high`` also draws the bodies with 2 x 2 samples a pixel, which
    antialiases their silhouettes, and, seen by a fixed camera, the terrain with ``TERRAIN_SAMPLES``
    x ``TERRAIN_SAMPLES`` samples a pixel, once for the whole run (its image is kept): the
    checker's edges and the terrain's outline antialiased as well as filtered.
    """

    TERRAIN_SAMPLES = 4  # a side, for a fixed camera at high quality
    STRIP_ROWS = 64  # image rows drawn at a time when supersampling the terrain (bounds its memory)

    def __init__(self, width: int, height: int, quality: str = "high"):
        from .quality import check_quality
        from .shadows import BodyPass, ShadowPass

        self.width, self.height = int(width), int(height)
        self.quality = check_quality(quality)
        self._terrains = {}  # id(view) -> _TerrainImage: each view's terrain image, kept
        self.shadow = ShadowPass() if self.quality in ("medium", "high") else None
        self.bodies = BodyPass(self.width, self.height, 2 if self.quality == "high" else 1)

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def render(self, view: SimulationView, cam: CameraSpec, update: bool = True) -> np.ndarray:
        """Draw ``view`` (its current state unless ``update`` is False) seen by ``cam``.

        Returns uint8 RGB [height, width, 3], row 0 at the top.

        The terrain and the bodies are drawn apart: the terrain's image (keys) is kept while the
        terrain and the camera stay the same (a fixed camera: drawn once per run), the bodies are
        drawn every frame into ``self.bodies`` and composited over it in the resolve.
        """
        if view.show_particles or view.show_springs:
            raise ValueError("the taichi renderer draws surfaces and terrain only; particles and springs need GGUI")
        if update:
            view.update()
        rig = light_rig(cam)
        ss = self.TERRAIN_SAMPLES if self.quality == "high" and not cam.follow else 1
        # The checker is filtered for the footprint of the samples it is drawn with.
        view.light(rig, (cam, ss * self.width, ss * self.height))
        meshes = view.lit_meshes()
        bodies = [m for m in meshes if m.body]
        shadow = fine = None
        if bodies:
            pts = view.surface.vertices.to_numpy()
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
                lo = hi = None
            terrain = view.sim.terrain
            if lo is not None and self.shadow is not None and self.shadow.prepare(
                    cam, self.width, self.height, rig.key_position, lo, hi, terrain.kind, terrain.params()):
                shadow = self.shadow
                for m in bodies:
                    shadow.cast(m.vertices, m.indices, m.colors)
            fine = self.bodies
            if lo is None:  # a non-finite state: drawn over the whole frame
                fine.raster.begin(cam, BACKGROUND)
                fine.rect = np.array([0, 0, self.width, self.height], np.int32)
            else:
                fine.prepare(cam, BACKGROUND, lo, hi)
            for m in bodies:
                fine.raster.draw(m.vertices, m.indices, m.colors, cull=m.closed, share=m.share,
                                 light=None if shadow is None else rig.key_position)
        kept = self._terrain_image(view)
        kept.raster.begin(cam, BACKGROUND)
        if kept.drawn != (view.terrain_version, cam):
            kept.raster.clear()
            terrain = [m for m in meshes if not m.body]
            for m in terrain:
                kept.raster.draw(m.vertices, m.indices, m.colors, cull=m.closed, share=m.share)
            kept.color = self._supersample(terrain, cam, ss, kept.color) if ss > 1 else None
            kept.drawn = (view.terrain_version, cam)
        image = kept.raster.finish(shadow, fine, keep=True, color=kept.color)
        if shadow is not None:
            shadow.clear()
        return image

    KEPT_VIEWS = 8  # terrain images kept (``compare`` draws one view per tile with one renderer)

    def _terrain_image(self, view) -> "_TerrainImage":
        """The terrain image kept for ``view`` (a new, undrawn one the first time)."""
        from .raster import TaichiRasterizer

        kept = self._terrains.get(id(view))
        if kept is None or kept.view is not view:
            if len(self._terrains) >= self.KEPT_VIEWS:
                self._terrains.pop(next(iter(self._terrains)))
            kept = self._terrains[id(view)] = _TerrainImage(view, TaichiRasterizer(self.width, self.height))
        return kept

    def _supersample(self, terrain, cam: CameraSpec, ss: int, color=None):
        """The terrain's colours [height, width] (f32 vec3, 0-255) averaged over ss x ss samples a
        pixel, into ``color`` (a new field if None), drawn in strips of ``STRIP_ROWS`` image rows
        (a strip's projection is the image's with its rows stretched and shifted into the strip)."""
        from .raster import TaichiRasterizer

        if color is None:
            color = ti.Vector.field(3, ti.f32, (self.height, self.width))
        rows = min(self.STRIP_ROWS, self.height)
        if getattr(self, "_strip", None) is None or self._strip.width != ss * self.width:
            self._strip = TaichiRasterizer(ss * self.width, ss * rows)
        strip = self._strip
        mvp = projection_matrix(cam, self.aspect) @ view_matrix(cam)
        for row0 in range(0, self.height, rows):
            # Image row r has ndc y = 1 - 2 r / H; in the strip it is row r - row0 of ``rows``.
            to_strip = np.eye(4)
            to_strip[1, 1] = self.height / rows
            to_strip[1, 3] = 1.0 - (self.height - 2.0 * row0) / rows
            strip.begin_matrix(to_strip @ mvp, BACKGROUND)
            for m in terrain:
                strip.draw(m.vertices, m.indices, m.colors, cull=m.closed)
            strip.downsample_into(color, row0, ss)
        return color

    def close(self):
        pass
