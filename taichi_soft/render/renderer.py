"""Offscreen GGUI rendering: one hidden window, any number of simulations drawn into it.

``Renderer(width, height)`` owns the window (Taichi must be initialised first; GGUI brings up
its own Vulkan device, also with ``arch=cpu``). ``SimulationView(sim)`` holds what one
simulation draws: its surface mesh, terrain meshes and optional particles and springs.
``renderer.render(view, camera)`` returns the frame as uint8 RGB [height, width, 3].
"""

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


def open_window(width: int, height: int):
    """A hidden GGUI window; no Vulkan device raises ``UserError`` with one line saying so."""
    try:
        return ti.ui.Window("taichi-soft", (width, height), show_window=False, vsync=False)
    except Exception as e:  # noqa: BLE001 - GGUI raises a bare RuntimeError for a missing device
        reason = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
        raise UserError(f"offscreen rendering needs a Vulkan device and none is usable here ({reason}); "
                        "install a Vulkan driver (without a GPU: Mesa's lavapipe, package mesa-vulkan-drivers)"
                        ) from None


class _StaticMesh:
    """A ``TriMesh`` uploaded once into the f32 fields GGUI draws from."""

    def __init__(self, mesh: TriMesh):
        n = len(mesh.vertices)
        self.vertices = ti.Vector.field(3, ti.f32, n)
        self.normals = ti.Vector.field(3, ti.f32, n)
        self.colors = ti.Vector.field(3, ti.f32, n)
        self.indices = ti.field(ti.i32, mesh.triangles.size)
        self.vertices.from_numpy(mesh.vertices.astype(np.float32))
        self.normals.from_numpy(mesh.normals.astype(np.float32))
        self.colors.from_numpy(mesh.colors.astype(np.float32))
        self.indices.from_numpy(mesh.triangles.astype(np.int32).ravel())
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
        # Particle radius [m]: a fifth of the finest lattice spacing, so neighbours never touch.
        self.particle_radius = 0.2 * min(b.spec.size / (b.spec.n - 1) for b in model.bodies)
        self.spring_ranges = {}
        if springs and model.n_springs:
            kind = model.group_np % 3
            order = np.argsort(kind, kind="stable")  # springs grouped by kind: one draw call each
            self.spring_indices = ti.field(ti.i32, 2 * model.n_springs)
            self.spring_indices.from_numpy(model.pairs_np[order].astype(np.int32).ravel())
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
                scene.mesh(s.vertices, s.indices, s.normals, color=BODY_COLORS[b % len(BODY_COLORS)],
                           index_offset=first, index_count=count)
        if self.show_springs:
            for name, (first, count) in self.spring_ranges.items():
                if count:
                    scene.lines(self.points, width=1.0, indices=self.spring_indices, color=SPRING_COLORS[name],
                                index_offset=first, index_count=count)
        if self.show_particles:
            scene.particles(self.points, radius=self.particle_radius, color=PARTICLE_COLOR)


class Renderer:
    """A hidden ``width`` x ``height`` pixel GGUI window that renders views to numpy images."""

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
