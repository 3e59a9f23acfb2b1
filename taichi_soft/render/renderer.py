"""Offscreen rendering: any number of simulations drawn by one renderer.

``SimulationView(sim)`` holds what one simulation draws: its surface mesh, terrain meshes and
optional particles and springs, lit per vertex (``lighting.py``). Two renderers draw views
(Taichi must be initialised first), both with ``render(view, camera)`` returning the frame as
uint8 RGB [height, width, 3]: ``Renderer(width, height)`` owns a hidden GGUI window (GGUI brings
up its own Vulkan device, also with ``arch=cpu``); ``taichi_renderer.TaichiRenderer(width,
height)`` rasterizes in Taichi kernels (``raster.py``), surfaces and terrain only, with shadows. ``choose.make_renderer`` picks one.
"""

from typing import NamedTuple

import numpy as np
import taichi as ti

from ..sim.lattice import SPRING_KINDS
from ..sim.spring_codes import group_kind
from .camera import CameraSpec, projection_matrix, view_matrix
from .embedded import body_surface
from .lighting import LightRig, apply_rig_to_ggui, light_rig, shade
from .meshes import BODY_COLORS, TriMesh, fade_checker, terrain_meshes
from .window import open_window, window_rgb

BACKGROUND = (0.86, 0.89, 0.93)
SPRING_COLORS = {"stretch": (0.15, 0.35, 0.95), "shear": (0.10, 0.70, 0.25), "bend": (0.85, 0.15, 0.70)}
PARTICLE_COLOR = (0.12, 0.12, 0.15)
_RIG_ATTR = "_taichi_soft_rig"  # where ``apply_camera`` leaves the light rig on a ti.ui.Scene for ``draw_view``
_SPEC_ATTR = "_taichi_soft_camera"  # and the camera it aimed


def aim_camera(camera, spec: CameraSpec):
    """Point a ``ti.ui.Camera`` as ``spec`` says (position, look-at, up, vertical fov)."""
    camera.position(*spec.position)
    camera.lookat(*spec.lookat)
    camera.up(*spec.up)
    camera.fov(spec.fov)


def apply_camera(scene, camera, spec: CameraSpec) -> LightRig:
    """Aim ``camera`` (a ``ti.ui.Camera``) by ``spec``, make it ``scene``'s (a ``ti.ui.Scene``) and
    light the scene from it (``lighting.light_rig``: ambient, warm key light above and left of the
    camera, cool fill light). Call once per frame, before ``draw_view``; returns the rig.

    The rig is kept with ``scene``: ``draw_view`` lights the vertices with it (per-vertex
    lighting) or hands it to GGUI (per-pixel, ``SimulationView.per_pixel_lighting``).
    """
    aim_camera(camera, spec)
    scene.set_camera(camera)
    rig = light_rig(spec)
    setattr(scene, _RIG_ATTR, rig)
    setattr(scene, _SPEC_ATTR, spec)
    return rig


def draw_view(canvas, scene, view: "SimulationView", size=None):
    """Draw ``view`` into ``scene`` and the scene onto ``canvas`` over the ``BACKGROUND`` colour
    (the camera and lights set first, by ``apply_camera``). ``size`` = (width, height) of the
    image [px]: the terrain's checker is filtered for it (``meshes.fade_checker``)."""
    rig = getattr(scene, _RIG_ATTR, None)
    if rig is None:
        raise RuntimeError("draw_view needs apply_camera(scene, ...) first: it sets the camera and the lights")
    spec = getattr(scene, _SPEC_ATTR, None)
    view.draw(scene, rig, None if size is None or spec is None else (spec, int(size[0]), int(size[1])))
    canvas.set_background_color(BACKGROUND)
    canvas.scene(scene)


def _identity_transform():
    """A one-instance 4x4 f32 identity transform field (see ``draw_mesh``)."""
    m = ti.Matrix.field(4, 4, ti.f32, 1)
    m.from_numpy(np.eye(4, dtype=np.float32)[None])
    return m


def draw_mesh(scene, identity, vertices, indices, normals, colors, two_sided=False):
    """Draw a triangle mesh (Taichi fields: vertices, triangle ``indices``, unit normals,
    per-vertex colours) into ``scene`` through ``mesh_instance`` with the one-instance
    ``identity`` transform (``_identity_transform()``).

    Why not ``scene.mesh``: GGUI 1.7.4's mesh vertex shader always reads an instance transform,
    ``model = I * (1 - has_attribute) + transform * has_attribute``, and for a plain mesh the
    64-byte transform buffer is allocated but never written (``renderables/mesh.cpp``). When that
    uninitialised memory holds an Inf or NaN, 0 * Inf = NaN turns every vertex into NaN and the
    whole mesh is silently dropped; the recycled allocation keeps the same bytes, so the mesh
    stayed missing in every frame of that view. An explicit identity transform is defined memory
    (docs/decisions/ggui-mesh-instance-transform.md).
    """
    scene.mesh_instance(vertices, indices, normals, per_vertex_color=colors, two_sided=two_sided, transforms=identity)


class LitMesh(NamedTuple):
    """Fields of a mesh ready to draw: f32 vec3 ``vertices`` [m], i32 triangle corners
    ``indices``, unit ``normals``, ``colors`` lit per vertex; ``closed``: faces seen from behind
    are hidden (``TriMesh.closed``); ``share``: f32, the key light's share of each vertex colour
    (what a shadow takes away, ``lighting.shade``)."""

    vertices: object
    indices: object
    normals: object
    colors: object
    closed: bool
    share: object = None
    body: bool = False  # a body's surface (casts shadows), not terrain


class _StaticMesh:
    """A ``TriMesh`` uploaded once into the f32 fields GGUI draws from, with its lit vertex
    colours (``lit``), relit only when the light rig or the camera changes (a fixed camera: once
    per run). A checkerboard is faded for its footprint on screen first (``meshes.fade_checker``)."""

    def __init__(self, mesh: TriMesh):
        n = len(mesh.vertices)
        self.vertices = ti.Vector.field(3, ti.f32, n)
        self.normals = ti.Vector.field(3, ti.f32, n)
        self.colors = ti.Vector.field(3, ti.f32, n)
        self.lit = ti.Vector.field(3, ti.f32, n)
        self.share = ti.field(ti.f32, n)
        self.checker_tile = mesh.checker_tile
        if self.checker_tile:
            self.faded = ti.Vector.field(3, ti.f32, n)
            self.checker_mean = np.unique(mesh.colors, axis=0).mean(axis=0)
        self.indices = ti.field(ti.i32, mesh.triangles.size)
        self.vertices.from_numpy(mesh.vertices.astype(np.float32))
        self.normals.from_numpy(mesh.normals.astype(np.float32))
        self.colors.from_numpy(mesh.colors.astype(np.float32))
        self.indices.from_numpy(np.ascontiguousarray(mesh.triangles, dtype=np.int32).ravel())
        self.two_sided, self.closed = mesh.two_sided, mesh.closed
        self._lit_by = None
        self.base = self.colors  # the colours lit: ``colors``, or ``faded`` for the last camera

    def light(self, rig: LightRig, viewport=None):
        """Light for ``rig``; ``viewport`` = (camera, width, height) filters a checkerboard for it."""
        if (rig, viewport) != self._lit_by:
            base = self.colors
            if self.checker_tile and viewport is not None:
                cam, width, height = viewport
                mvp = projection_matrix(cam, width / height) @ view_matrix(cam)
                fade_checker(self.vertices, self.colors, self.faded, self.checker_tile, self.checker_mean, mvp,
                             width, height)
                base = self.faded
            self.base = base
            shade(self.vertices, self.normals, base, self.lit, self.share, rig, self.two_sided)
            self._lit_by = (rig, viewport)

    def lit_mesh(self) -> "LitMesh":
        return LitMesh(self.vertices, self.indices, self.normals, self.lit, self.closed, self.share)


@ti.data_oriented
class SimulationView:
    """What one ``Simulation`` draws; ``update()`` pulls the current state onto the draw fields.

    ``surface``: each body's outer surface, smooth-shaded, one colour per body.
    ``particles``: every particle as a small sphere. ``springs``: springs as lines, stretch,
    shear and bend each in its own colour (``SPRING_COLORS``): True for every kind, or the kind
    names to draw (e.g. ``{"stretch", "bend"}``).

    ``show_surface``, ``show_particles`` and ``show_springs`` (same values as the arguments) can be
    changed between frames; particles and springs can only be shown by a view built with them.

    Lighting (``lighting.py``): meshes are lit per vertex in a Taichi kernel and GGUI only
    interpolates the colours, which on lavapipe costs about half of GGUI's own per-pixel lighting.
    ``per_pixel_lighting = True`` hands the lights to GGUI instead (the reference look); so does a
    frame that shows particles, since GGUI lights its particle spheres itself.
    """

    def __init__(self, sim, surface: bool = True, particles: bool = False, springs=False):
        self.sim = sim
        model = sim.model
        self.show_surface, self.show_particles, self.show_springs = surface, particles, springs
        springs = bool(self.show_springs)  # any kind: the index array of every kind is built
        self.surface = body_surface(model)  # mesh bodies: their input mesh, embedded (embedded.py)
        self._identity = _identity_transform()
        # One draw call for every body: per-vertex colours, one colour per body.
        self.body_colors = ti.Vector.field(3, ti.f32, self.surface.n_vertices)
        palette = np.asarray(BODY_COLORS, dtype=np.float32)
        self.body_colors.from_numpy(palette[self.surface.vertex_body % len(palette)])
        self.surface_lit = ti.Vector.field(3, ti.f32, self.surface.n_vertices)  # body colours lit per vertex
        self.surface_share = ti.field(ti.f32, self.surface.n_vertices)  # their key light's share
        self.per_pixel_lighting = False
        self._terrain_params = None
        self.terrain_version = 0  # counts terrain rebuilds (a renderer may keep the terrain's image)
        self.terrain: list[_StaticMesh] = []
        self._sync_terrain()
        self.points = None
        if particles or springs:
            self.points = ti.Vector.field(3, ti.f32, model.n_particles)
        # Particle radius [m]: a tenth of the finest lattice spacing (GGUI draws them as screen-facing
        # spheres that look larger than that), so neighbours stay apart.
        self.particle_radius = 0.1 * min(b.spec.size / (b.spec.n - 1) for b in model.bodies)
        self.spring_ranges = {}
        if springs and model.n_springs:
            kind = group_kind(model.group_np)
            order = np.argsort(kind, kind="stable")  # springs grouped by kind: one draw call each
            self.spring_indices = np.ascontiguousarray(model.pairs_np[order], dtype=np.int32).ravel()
            counts = np.bincount(kind, minlength=3)
            starts = np.concatenate([[0], np.cumsum(counts)])
            self.spring_ranges = {name: (2 * int(starts[k]), 2 * int(counts[k])) for k, name in enumerate(SPRING_KINDS)}

    @property
    def show_springs(self) -> frozenset:
        """The spring kinds drawn (a subset of ``SPRING_KINDS``); set True (all), False (none) or kind names."""
        return self._show_springs

    @show_springs.setter
    def show_springs(self, kinds):
        if isinstance(kinds, (bool, np.bool_)):
            kinds = SPRING_KINDS if kinds else ()
        elif isinstance(kinds, str):
            kinds = (kinds,)
        unknown = set(kinds) - set(SPRING_KINDS)
        if unknown:
            raise ValueError(f"unknown spring kind(s) {sorted(unknown)}; choose from {', '.join(SPRING_KINDS)}")
        self._show_springs = frozenset(kinds)

    @ti.kernel
    def _gather_points(self, x: ti.template()):
        for i in x:
            self.points[i] = ti.cast(x[i], ti.f32)

    def _sync_terrain(self):
        """(Re)build the terrain meshes when the live terrain's geometry differs from the drawn one.

        Drawn from ``sim.terrain`` itself (kind and ``params()``), not from the scene file, so a
        geometry changed at run time (``set_geometry``) is drawn where the bodies now collide.
        """
        terrain = self.sim.terrain
        params = (terrain.kind, terrain.params())
        if params != self._terrain_params:
            self._terrain_params = params
            self.terrain_version += 1
            self.terrain = [_StaticMesh(m) for m in terrain_meshes(params[0], params[1], self.sim.scene.data)]

    def update(self):
        """Copy the simulation's current positions into the draw fields (normals included) and
        follow any change of the terrain's geometry."""
        self._sync_terrain()
        x = self.sim.state.x
        self.surface.update(x)
        if self.points is not None:
            self._gather_points(x)

    def light(self, rig: LightRig, viewport=None):
        """Light the drawn meshes' vertices with ``rig`` (the terrain only when the rig or the
        camera changed). ``viewport`` = (``CameraSpec``, width, height [px]) of the image: the
        terrain's checker is filtered for that view (``meshes.fade_checker``); None draws it raw."""
        for mesh in self.terrain:
            mesh.light(rig, viewport)
        if self.show_surface:
            s = self.surface
            shade(s.vertices, s.normals, self.body_colors, self.surface_lit, self.surface_share, rig)

    def lit_meshes(self) -> list[LitMesh]:
        """Every mesh drawn, with the vertex colours of the last ``light``."""
        meshes = [m.lit_mesh() for m in self.terrain]
        if self.show_surface:
            s = self.surface
            meshes.append(LitMesh(s.vertices, s.indices, s.normals, self.surface_lit, True, self.surface_share, True))
        return meshes

    def draw(self, scene, rig: LightRig, viewport=None):
        """Queue the view's meshes, lines and particles into a GGUI ``scene`` lit by ``rig``;
        ``viewport`` as for ``light``."""
        if self.per_pixel_lighting or self.show_particles:
            apply_rig_to_ggui(scene, rig)
            for m in self.terrain:
                m.light(rig, viewport)  # only for the checker's filtered colours
                draw_mesh(scene, self._identity, m.vertices, m.indices, m.normals, m.base, m.two_sided)
            if self.show_surface:
                s = self.surface
                draw_mesh(scene, self._identity, s.vertices, s.indices, s.normals, self.body_colors)
        else:
            scene.ambient_light((1.0, 1.0, 1.0))  # the vertex colours are lit already: GGUI passes them on
            self.light(rig, viewport)
            for m in self.lit_meshes():
                draw_mesh(scene, self._identity, m.vertices, m.indices, m.normals, m.colors)
        for name, (first, count) in self.spring_ranges.items():
            if name in self._show_springs and count:
                # vertex_count only matters for unindexed lines; GGUI prints a warning every frame
                # when it is odd (its default: the particle count), so pass an even one.
                scene.lines(self.points, width=1.0, indices=self.spring_indices, color=SPRING_COLORS[name],
                            index_offset=first, index_count=count, vertex_count=self.points.shape[0] // 2 * 2)
        if self.show_particles:
            scene.particles(self.points, radius=self.particle_radius, color=PARTICLE_COLOR)


class Renderer:
    """A hidden ``width`` x ``height`` pixel GGUI window that renders views to numpy images.

    GGUI copies vertex and index data into its own buffers during each draw call, so views may
    be built, drawn and dropped in any order (meshes are drawn through ``draw_mesh``).
    """

    def __init__(self, width: int, height: int):
        self.width, self.height = int(width), int(height)
        self.window = open_window(self.width, self.height)
        self.canvas = self.window.get_canvas()
        self.scene = self.window.get_scene()
        self.camera = ti.ui.Camera()

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def render(self, view: SimulationView, cam: CameraSpec, update: bool = True) -> np.ndarray:
        """Draw ``view`` (its current state unless ``update`` is False) seen by ``cam``.

        Returns uint8 RGB [height, width, 3], row 0 at the top.
        """
        if update:
            view.update()
        apply_camera(self.scene, self.camera, cam)
        draw_view(self.canvas, self.scene, view, (self.width, self.height))
        return self.read_image()

    def read_image(self) -> np.ndarray:
        """The rendered frame as uint8 RGB [height, width, 3], top row first (``window_rgb``)."""
        return window_rgb(self.window)

    def close(self):
        self.window.destroy()
