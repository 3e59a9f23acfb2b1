"""Terrains: the shapes bodies collide with, and the seed's contact model.

Each terrain class compiles only its own geometry (a scene with a plane compiles no sphere
code): kernels call ``terrain.query(i, x)``, which is a ``ti.func`` of the concrete class.
Contact model (after the seed, see REFERENCE.md):

* detection: signed distance d < epsilon to the surface, with the normal N pointing to the side
  the particle belongs on;
* while in contact and pressed (N . f < 0) a contact force cancels the normal push and Coulomb
  friction of magnitude mu |N . f| opposes tangential sliding; it may stop a particle, never
  reverse it (``contact_accel``);
* after each step, penetrating particles are projected back to the surface and an approaching
  normal velocity is reflected with restitution: v' = -kr v_N + v_T (``respond``).

Parameters (restitution, friction, epsilon, geometry) live in 0-d fields so they can be tuned
between steps without recompiling.
"""

import numpy as np
import taichi as ti

KINDS = ("none", "plane", "tilted_plane", "sphere", "bowl")

# Geometry parameters each terrain kind accepts, with defaults from the assignment.
DEFAULTS = {
    "none": {},
    "plane": {"point": [0.0, -1.0, 0.0], "normal": [0.0, 1.0, 0.0]},
    "tilted_plane": {"point": [0.0, 0.0, 0.0], "normal": [1.0, 1.0, 0.0]},
    "sphere": {"center": [0.0, -1.0, 0.0], "radius": 3.0},
    "bowl": {"center": [2.0, 7.0, 1.0], "radius": 7.0},
}


@ti.data_oriented
class Terrain:
    """Base class: contact parameters and the contact/response functions shared by all shapes.

    Subclasses implement ``query(i, x) -> (d, N)``: signed distance [m] (negative = inside the
    terrain) and unit normal pointing out of it, for particle i at position x.
    """

    kind = "base"
    has_contact = True

    def __init__(self, n_particles: int, restitution=0.8, friction=0.3, epsilon=0.01):
        self.n_particles = n_particles
        self.restitution = ti.field(float, ())  # kr in [0, 1]
        self.friction = ti.field(float, ())  # Coulomb mu >= 0
        self.epsilon = ti.field(float, ())  # contact detection distance [m]
        self.set_contact(restitution, friction, epsilon)

    def set_contact(self, restitution=None, friction=None, epsilon=None):
        """Set restitution [-], friction coefficient [-] and contact distance epsilon [m]."""
        if restitution is not None:
            self.restitution[None] = restitution
        if friction is not None:
            self.friction[None] = friction
        if epsilon is not None:
            self.epsilon[None] = epsilon

    def reset(self, x: ti.template()):
        """Called when a state is (re)initialised; shapes with per-particle memory override it."""

    def params(self) -> dict:
        """Geometry parameters as plain Python values (for renderers and summaries)."""
        return {}

    @ti.func
    def post_step(self, i, x):
        """Per-particle bookkeeping after a step (the bowl tracks which side a particle is on)."""
        pass

    @ti.func
    def contact_accel(self, i, x, v, a, dt):
        """Acceleration of particle i after contact and friction forces.

        ``a`` is the acceleration from gravity, springs and dampers [m/s^2]. Friction is
        capped so that within a step of ``dt`` it brings the tangential velocity at most to zero.
        """
        d, n = self.query(i, x)
        if d < self.epsilon[None]:
            an = n.dot(a)
            if an < 0:  # pressed into the surface: contact force cancels the normal push
                a -= an * n
                # Trial tangential velocity after this step without friction.
                trial = v - n.dot(v) * n + dt * a
                tn = trial.norm()
                if tn > 0:
                    mag = ti.min(self.friction[None] * (-an), tn / dt)
                    a -= mag / tn * trial
        return a

    @ti.func
    def respond(self, i, x, v):
        """Project a penetrating particle to the surface and reflect its approaching velocity."""
        d, n = self.query(i, x)
        if d < 0:
            x -= d * n
        if d < self.epsilon[None]:
            vn = n.dot(v)
            if vn < 0:
                v -= (1.0 + self.restitution[None]) * vn * n
        self.post_step(i, x)
        return x, v


class NoTerrain(Terrain):
    """Empty space: nothing to collide with; kernels skip contact code entirely."""

    kind = "none"
    has_contact = False

    @ti.func
    def query(self, i, x):
        return ti.cast(1e30, float), ti.Vector([0.0, 1.0, 0.0], dt=float)


class Plane(Terrain):
    """Half-space N . (x - p) >= 0; bodies stay on the side the normal points to."""

    kind = "plane"

    def __init__(self, n_particles, point=(0.0, -1.0, 0.0), normal=(0.0, 1.0, 0.0), **contact):
        super().__init__(n_particles, **contact)
        self.point = ti.Vector.field(3, float, ())
        self.normal = ti.Vector.field(3, float, ())
        self.set_geometry(point, normal)

    def set_geometry(self, point, normal):
        """Point on the plane [m] and its normal (any length > 0; normalised here)."""
        nrm = np.asarray(normal, dtype=np.float64)
        self.point[None] = tuple(float(c) for c in point)
        self.normal[None] = tuple(nrm / np.linalg.norm(nrm))

    def params(self):
        return {"point": list(self.point[None].to_numpy().tolist()),
                "normal": list(self.normal[None].to_numpy().tolist())}

    @ti.func
    def query(self, i, x):
        n = self.normal[None]
        return n.dot(x - self.point[None]), n


class TiltedPlane(Plane):
    """A plane through a point with a tilted normal (default: origin, normal (1, 1, 0), 45 deg)."""

    kind = "tilted_plane"

    def __init__(self, n_particles, point=(0.0, 0.0, 0.0), normal=(1.0, 1.0, 0.0), **contact):
        super().__init__(n_particles, point, normal, **contact)


class Sphere(Terrain):
    """Solid ball of radius r around c; bodies stay outside."""

    kind = "sphere"

    def __init__(self, n_particles, center=(0.0, -1.0, 0.0), radius=3.0, **contact):
        super().__init__(n_particles, **contact)
        self.center = ti.Vector.field(3, float, ())
        self.radius = ti.field(float, ())
        self.set_geometry(center, radius)

    def set_geometry(self, center, radius):
        """Centre [m] and radius [m]."""
        self.center[None] = tuple(float(c) for c in center)
        self.radius[None] = float(radius)

    def params(self):
        return {"center": self.center[None].to_numpy().tolist(), "radius": float(self.radius[None])}

    @ti.func
    def query(self, i, x):
        r = x - self.center[None]
        dist = r.norm()
        n = ti.Vector([0.0, 1.0, 0.0], dt=float)
        if dist > 0:
            n = r / dist
        return dist - self.radius[None], n


class Bowl(Sphere):
    """Lower half of a thin spherical shell (centre c, radius r), open at the top.

    The shell has two sides. A particle's side (inside / outside) is remembered per particle and
    may change only above the rim plane y = c.y, where it is decided by the horizontal distance
    to the axis; below the rim plane the shell keeps it on its side, so a body resting inside the
    bowl never tunnels out, and one landing on the outside or the rim does not fall through.
    Above the rim plane the nearest part of the shell is the rim circle.
    """

    kind = "bowl"

    def __init__(self, n_particles, center=(2.0, 7.0, 1.0), radius=7.0, **contact):
        super().__init__(n_particles, center, radius, **contact)
        self.inside = ti.field(ti.i8, n_particles)  # 1 = inside the bowl, 0 = outside

    @ti.kernel
    def reset(self, x: ti.template()):
        for i in range(self.n_particles):
            r = x[i] - self.center[None]
            if r.y >= 0:
                self.inside[i] = ti.cast(ti.Vector([r.x, r.z]).norm() < self.radius[None], ti.i8)
            else:
                self.inside[i] = ti.cast(r.norm() < self.radius[None], ti.i8)

    @ti.func
    def post_step(self, i, x):
        r = x - self.center[None]
        if r.y >= 0:
            self.inside[i] = ti.cast(ti.Vector([r.x, r.z]).norm() < self.radius[None], ti.i8)

    @ti.func
    def query(self, i, x):
        c = self.center[None]
        rad = self.radius[None]
        r = x - c
        d = ti.cast(0.0, float)
        n = ti.Vector([0.0, 1.0, 0.0], dt=float)
        if r.y >= 0:
            # Above the rim plane: distance to the rim circle.
            h = ti.Vector([r.x, 0.0, r.z], dt=float)
            hn = h.norm()
            rim_dir = ti.Vector([1.0, 0.0, 0.0], dt=float)
            if hn > 0:
                rim_dir = h / hn
            e = x - (c + rad * rim_dir)
            d = e.norm()
            if d > 0:
                n = e / d
        else:
            dist = r.norm()
            radial = r / ti.max(dist, 1e-30)
            if self.inside[i]:
                d = rad - dist
                n = -radial
            else:
                d = dist - rad
                n = radial
        return d, n


CLASSES = {"none": NoTerrain, "plane": Plane, "tilted_plane": TiltedPlane, "sphere": Sphere, "bowl": Bowl}


def make_terrain(kind: str, n_particles: int, geometry: dict, restitution: float, friction: float,
                 epsilon: float) -> Terrain:
    """Build the terrain of ``kind`` with its geometry parameters and contact coefficients."""
    cls = CLASSES[kind]
    return cls(n_particles, **geometry, restitution=restitution, friction=friction, epsilon=epsilon)
