"""Offscreen GGUI rendering: one hidden window, any number of simulations drawn into it.

``Renderer(width, height)`` owns the window (Taichi must be initialised first; GGUI brings up
its own Vulkan device, also with ``arch=cpu``). ``SimulationView(sim)`` holds what one
simulation draws: its surface mesh, terrain meshes and optional particles and springs.
``renderer.render(view, camera)`` returns the frame as uint8 RGB [height, width, 3].
"""

import contextlib
import os
import sys
import tempfile

import numpy as np
import taichi as ti

from ..errors import UserError
from ..lattice import SPRING_KINDS
from .camera import CameraSpec
from .meshes import BODY_COLORS, SurfaceMesh, TriMesh, terrain_meshes

BACKGROUND = (0.86, 0.89, 0.93)
SPRING_COLORS = {"stretch": (0.15, 0.35, 0.95), "shear": (0.10, 0.70, 0.25), "bend": (0.85, 0.15, 0.70)}
PARTICLE_COLOR = (0.12, 0.12, 0.15)
AMBIENT = (0.30, 0.30, 0.32)
KEY_LIGHT = (0.72, 0.70, 0.66)  # warm, above and left of the camera
FILL_LIGHT = (0.18, 0.20, 0.24)  # cool, from the other side: faces turned away stay readable


@contextlib.contextmanager
def _stderr_captured():
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


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[-1] if lines else ""


def open_window(width: int, height: int):
    """A hidden GGUI window; no Vulkan device raises ``UserError`` with one line saying so."""
    with _stderr_captured() as native:
        try:
            return ti.ui.Window("taichi-soft", (width, height), show_window=False, vsync=False)
        except Exception as e:  # noqa: BLE001 - GGUI raises a bare RuntimeError for a missing device
            error = e
    reason = "; ".join(r for r in (_last_line(str(error)) or type(error).__name__, _last_line(native[0])) if r)
    raise UserError(f"offscreen rendering needs a Vulkan device and none is usable here ({reason}); "
                    "install a Vulkan driver (without a GPU: Mesa's lavapipe, package mesa-vulkan-drivers)")


class _StaticMesh:
    """A ``TriMesh`` uploaded once into the f32 fields GGUI draws from."""

    def __init__(self, mesh: TriMesh):
        n = len(mesh.vertices)
        self.vertices = ti.Vector.field(3, ti.f32, n)
        self.normals = ti.Vector.field(3, ti.f32, n)
        self.colors = ti.Vector.field(3, ti.f32, n)
        self.vertices.from_numpy(mesh.vertices.astype(np.float32))
        self.normals.from_numpy(mesh.normals.astype(np.float32))
        self.colors.from_numpy(mesh.colors.astype(np.float32))
        # Indices go to GGUI as a numpy array we keep alive (see ``Renderer`` on why).
        self.indices = np.ascontiguousarray(mesh.triangles, dtype=np.int32).ravel()
        self.two_sided = mesh.two_sided

    def draw(self, scene):
        scene.mesh(self.vertices, self.indices, self.normals, per_vertex_color=self.colors, two_sided=self.two_sided)


@ti.data_oriented
class SimulationView:
    """What one ``Simulation`` draws; ``update()`` pulls the current state onto the draw fields.

    ``surface``: each body's outer surface, smooth-shaded, one colour per body.
    ``particles``: every particle as a small sphere. ``springs``: every spring as a line, stretch,
    shear and bend each in its own colour (``SPRING_COLORS``).
    """

    def __init__(self, sim, surface: bool = True, particles: bool = False, springs: bool = False):
        self.sim = sim
        model = sim.model
        self.show_surface, self.show_particles, self.show_springs = surface, particles, springs
        self.surface = SurfaceMesh(model)
        self.terrain = [_StaticMesh(m) for m in terrain_meshes(sim.scene.data)]
        self.points = None
        if particles or springs:
            self.points = ti.Vector.field(3, ti.f32, model.n_particles)
        # Particle radius [m]: a tenth of the finest lattice spacing (GGUI draws them as screen-facing
        # spheres that look larger than that), so neighbours stay apart.
        self.particle_radius = 0.1 * min(b.spec.size / (b.spec.n - 1) for b in model.bodies)
        self.spring_ranges = {}
        if springs and model.n_springs:
            kind = model.group_np % 3
            order = np.argsort(kind, kind="stable")  # springs grouped by kind: one draw call each
            self.spring_indices = np.ascontiguousarray(model.pairs_np[order], dtype=np.int32).ravel()
            counts = np.bincount(kind, minlength=3)
            starts = np.concatenate([[0], np.cumsum(counts)])
            self.spring_ranges = {name: (2 * int(starts[k]), 2 * int(counts[k])) for k, name in enumerate(SPRING_KINDS)}

    @ti.kernel
    def _gather_points(self, x: ti.template()):
        for i in x:
            self.points[i] = ti.cast(x[i], ti.f32)

    def update(self):
        """Copy the simulation's current positions into the draw fields (normals included)."""
        x = self.sim.state.x
        self.surface.update(x)
        if self.points is not None:
            self._gather_points(x)

    def draw(self, scene):
        for mesh in self.terrain:
            mesh.draw(scene)
        s = self.surface
        if self.show_surface:
            for b, (_, _, first, count) in enumerate(s.bodies):
                scene.mesh(s.vertices, s.index_array, s.normals, color=BODY_COLORS[b % len(BODY_COLORS)],
                           index_offset=first, index_count=count)
        if self.show_springs:
            for name, (first, count) in self.spring_ranges.items():
                if count:
                    scene.lines(self.points, width=1.0, indices=self.spring_indices, color=SPRING_COLORS[name],
                                index_offset=first, index_count=count)
        if self.show_particles:
            scene.particles(self.points, radius=self.particle_radius, color=PARTICLE_COLOR)


class Renderer:
    """A hidden ``width`` x ``height`` pixel GGUI window that renders views to numpy images.

    Triangle and line indices are handed to GGUI as numpy arrays owned by the views. Given a
    Taichi field instead, GGUI 1.7.4 copies it into a temporary numpy array per draw call and
    keeps only a raw pointer to it; when several draws share one index field (a body per draw),
    meshes intermittently went missing from frames.
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
        self._set_camera(cam)
        view.draw(self.scene)
        self.canvas.set_background_color(BACKGROUND)
        self.canvas.scene(self.scene)
        return self.read_image()

    def _set_camera(self, cam: CameraSpec):
        c = self.camera
        c.position(*cam.position)
        c.lookat(*cam.lookat)
        c.up(*cam.up)
        c.fov(cam.fov)
        self.scene.set_camera(c)
        # Lights move with the camera so every scene and every follow shot is lit the same way.
        eye, target = np.asarray(cam.position), np.asarray(cam.lookat)
        back = eye - target
        dist = np.linalg.norm(back)
        right = np.cross(-back, cam.up)
        right /= max(np.linalg.norm(right), 1e-12)
        up = np.asarray(cam.up, dtype=np.float64) / np.linalg.norm(cam.up)
        self.scene.ambient_light(AMBIENT)
        self.scene.point_light(tuple(target + back + dist * (0.9 * up - 0.5 * right)), KEY_LIGHT)
        self.scene.point_light(tuple(target + 0.6 * back + dist * (0.8 * right - 0.2 * up)), FILL_LIGHT)

    def read_image(self) -> np.ndarray:
        """The rendered frame as uint8 RGB [height, width, 3], top row first.

        GGUI hands back float32 [width, height, 4] with the origin at the bottom left.
        """
        buf = self.window.get_image_buffer_as_numpy()
        rgb = buf[:, ::-1, :3].transpose(1, 0, 2)
        return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)

    def close(self):
        self.window.destroy()
