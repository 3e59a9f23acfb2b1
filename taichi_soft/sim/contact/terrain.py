"""Terrains: the shapes bodies collide with, and the seed's contact model.

Each terrain class compiles only its own geometry (a scene with a plane compiles no sphere
code): kernels call ``terrain.query(i, x)``, which is a ``ti.func`` of the concrete class.
Contact model (after the seed, the course assignment this project grew from; see README "Contact"):

* detection: signed distance d < epsilon to the surface, with the normal N pointing to the side
  the particle belongs on;
* while in contact and pressed (N . f < 0) a contact force cancels the normal push and Coulomb
  friction of magnitude mu |N . f| opposes tangential sliding; it may stop a particle, never
  reverse it (``contact_accel``);
* after each step, penetrating particles are projected back to the surface and an approaching
  normal velocity v_N is removed (``respond``): reflected with restitution (v_N' = -kr v_N) only
  when the approach speed exceeds ``bounce_threshold``, else stopped (resting contact: a particle
  lying on the surface must not hop, or friction acts only part of the time); with
  ``impact_friction`` the tangential velocity is reduced by mu times the normal velocity change
  (Coulomb friction on the impact impulse), never reversed.

The seed's exact model (every approach reflected, v' = -kr v_N + v_T) is ``bounce_threshold = 0``
and ``impact_friction = false``. Parameters (restitution, friction, epsilon, threshold, geometry)
live in 0-d fields so they can be tuned between steps without recompiling.
"""

import numpy as np
import taichi as ti

from ..scalar_fields import assign

KINDS = ("none", "plane", "tilted_plane", "sphere", "bowl")

# Contact coefficients (the scene's [contact] table); the one home of their defaults.
# bounce_threshold: 1 m/s as in Box2D (b2_velocityThreshold): slower impacts are inelastic. It is
# far below this project's drops (a cube falling 8 m hits at ~12.5 m/s) and far above the
# sub-mm/s jitter of a particle resting on the surface.
# impact_at_crossing: false is the seed's rule (a particle is answered where the step's end finds it).
CONTACT_DEFAULTS = {"restitution": 0.8, "friction": 0.3, "epsilon": 0.01,
                    "bounce_threshold": 1.0, "impact_friction": True, "impact_at_crossing": False}

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

    def __init__(self, n_particles: int, **contact):
        self.n_particles = n_particles
        self.restitution = ti.field(float, ())  # kr in [0, 1]
        self.friction = ti.field(float, ())  # Coulomb mu >= 0
        self.epsilon = ti.field(float, ())  # contact detection distance [m]
        self.bounce_threshold = ti.field(float, ())  # slowest approach [m/s] that bounces
        self.impact_friction = ti.field(ti.i32, ())  # 1: Coulomb friction on the impact impulse
        self.impact_at_crossing = ti.field(ti.i32, ())  # 1: impacts answered at the crossing time
        self.set_contact(**{**CONTACT_DEFAULTS, **contact})

    def set_contact(self, restitution=None, friction=None, epsilon=None, bounce_threshold=None, impact_friction=None,
                    impact_at_crossing=None):
        """Set restitution [-], friction coefficient [-], contact distance epsilon [m], bounce
        threshold [m/s], whether friction acts on the impact impulse (bool) and whether the
        straight-drift methods answer an impact at its crossing time (bool, ``respond_path``)."""
        given = {self.restitution: restitution, self.friction: friction, self.epsilon: epsilon,
                 self.bounce_threshold: bounce_threshold,
                 self.impact_friction: None if impact_friction is None else int(bool(impact_friction)),
                 self.impact_at_crossing: None if impact_at_crossing is None else int(bool(impact_at_crossing))}
        assign({f: v for f, v in given.items() if v is not None})

    def reset(self, x: ti.template()):
        """Called when a state is (re)initialised; shapes with per-particle memory override it."""

    def params(self) -> dict:
        """Geometry parameters as plain Python values (for renderers and summaries)."""
        return {}

    def crossed(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Which segments a -> b ([n, 3] each, metres) the terrain's surface passes through: a body
        whose springs it crosses straddles the surface even when no particle is inside the terrain."""
        return np.zeros(len(a), dtype=bool)

    def signed_distances(self, x) -> np.ndarray:
        """Signed distance [m] of every particle at positions ``x`` (a vec3 field) to the surface,
        negative inside the terrain (call after ``reset``: the bowl's answer depends on it)."""
        out = np.full(self.n_particles, np.inf)
        if self.has_contact:
            self._k_distances(x, out)
        return out

    @ti.kernel
    def _k_distances(self, x: ti.template(), out: ti.types.ndarray()):
        for i in range(self.n_particles):
            d, _ = self.query(i, x[i])
            out[i] = d

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
        """Project a penetrating particle to the surface and remove its approaching velocity.

        Approach speeds above ``bounce_threshold`` [m/s] are reflected with restitution, slower
        ones stopped; with ``impact_friction`` the tangential velocity loses mu |dv_N| (at most
        all of it).
        """
        d, n = self.query(i, x)
        if d < 0:
            x -= d * n
        if d < self.epsilon[None]:
            vn = n.dot(v)
            if vn < 0:
                v = self.impact(v, n, vn)
        self.post_step(i, x)
        return x, v

    @ti.func
    def respond_path(self, i, x0, x1, v, a, dt):
        """``respond`` for a particle that drifted from ``x0`` to ``x1`` = x0 + dt v [m] during a
        step of ``dt`` [s]: ``v`` [m/s] is the mean velocity of the path, ``a`` [m/s^2] the
        acceleration along it (its velocity at fraction s of the step is v + (s - 1/2) dt a:
        velocity Verlet's drift; zero for semi-implicit Euler's constant-velocity drift).

        Without ``impact_at_crossing``: ``respond`` at ``x1``, the seed's end-of-step rule: an
        approach is answered wherever the step's end finds the particle in the contact band
        (d < epsilon) or inside. With it, when the approach happened: a particle that starts
        outside the band and ends in it (or inside) is moved back to where its path enters the band
        (the signed distance interpolated linearly along the path: exact for a plane), its velocity
        there answered with ``impact``, and advanced for the rest of the step. The same model at a
        finer time: both rules converge to one answer as dt -> 0. Then ``respond`` as always (it
        projects whatever is still inside, and answers a particle that started in the band).
        Returns (x1, v) with v the path's mean velocity as above, after the impact (so the method's
        last kick of dt/2 a ends at the velocity of the end of the step)."""
        xo, vo = x1, v
        if self.impact_at_crossing[None] != 0:
            eps = self.epsilon[None]
            d1, _ = self.query(i, x1)
            if d1 < eps:
                d0, _ = self.query(i, x0)
                if d0 > eps:
                    s = (d0 - eps) / (d0 - d1)  # the fraction of the step before the band's edge
                    xc = x0 + s * (x1 - x0)
                    _, n = self.query(i, xc)
                    vc = v + ((s - 0.5) * dt) * a
                    vn = n.dot(vc)
                    if vn < 0:
                        vc = self.impact(vc, n, vn)
                    rest = (1.0 - s) * dt
                    xo = xc + rest * (vc + (0.5 * rest) * a)
                    vo = vc + ((0.5 - s) * dt) * a
        return self.respond(i, xo, vo)

    @ti.func
    def impact(self, v, n, vn):
        """Velocity after an impact with approach velocity vn = v . n < 0 along unit normal n."""
        return self.impact_response(v, n, vn, self.impact_friction[None])

    @ti.func
    def impact_response(self, v, n, vn, with_friction):
        """``impact`` with friction on the impulse when ``with_friction`` (body-body contact, which
        has no force-level friction, always asks for it)."""
        kr = self.restitution[None] * ti.cast(-vn > self.bounce_threshold[None], float)
        vt = v - vn * n
        if with_friction:
            t = vt.norm()
            if t > 0:
                # Coulomb: the tangential impulse is at most mu times the normal one, dv_N = -(1 + kr) vn.
                vt *= ti.max(0.0, 1.0 - self.friction[None] * (1.0 + kr) * (-vn) / t)
        return vt - kr * vn * n


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

    def __init__(self, n_particles, point=None, normal=None, **contact):
        super().__init__(n_particles, **contact)
        geometry = DEFAULTS[self.kind]
        point = geometry["point"] if point is None else point
        normal = geometry["normal"] if normal is None else normal
        self.point = ti.Vector.field(3, float, ())
        self.normal = ti.Vector.field(3, float, ())
        self.set_geometry(point, normal)

    def set_geometry(self, point, normal):
        """Point on the plane [m] and its normal (any length > 0; normalised here)."""
        nrm = np.asarray(normal, dtype=np.float64)
        assign({self.point: point, self.normal: nrm / np.linalg.norm(nrm)})

    def params(self):
        return {"point": list(self.point[None].to_numpy().tolist()),
                "normal": list(self.normal[None].to_numpy().tolist())}

    def crossed(self, a, b):
        n, p = self.normal[None].to_numpy(), self.point[None].to_numpy()
        return np.sign((a - p) @ n) * np.sign((b - p) @ n) < 0

    @ti.func
    def query(self, i, x):
        n = self.normal[None]
        return n.dot(x - self.point[None]), n


class TiltedPlane(Plane):
    """A plane through a point with a tilted normal (default: origin, normal (1, 1, 0), 45 deg)."""

    kind = "tilted_plane"

    # Its default geometry (origin, normal (1, 1, 0): 45 degrees) comes from DEFAULTS[kind].


class Sphere(Terrain):
    """Solid ball of radius r around c; bodies stay outside."""

    kind = "sphere"

    def __init__(self, n_particles, center=None, radius=None, **contact):
        super().__init__(n_particles, **contact)
        geometry = DEFAULTS[self.kind]
        center = geometry["center"] if center is None else center
        radius = geometry["radius"] if radius is None else radius
        self.center = ti.Vector.field(3, float, ())
        self.radius = ti.field(float, ())
        self.set_geometry(center, radius)

    def set_geometry(self, center, radius):
        """Centre [m] and radius [m]."""
        assign({self.center: center, self.radius: radius})

    def params(self):
        return {"center": self.center[None].to_numpy().tolist(), "radius": float(self.radius[None])}

    def _sphere_crossings(self, a, b) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Segment parameters t0 <= t1 where a + t (b - a) meets the sphere |x - c| = r (NaN where the
        line misses it), and the segments b - a."""
        c, r = self.center[None].to_numpy(), float(self.radius[None])
        d, f = b - a, a - c
        dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
        half_b = np.einsum("ij,ij->i", f, d)
        disc = half_b ** 2 - dd * (np.einsum("ij,ij->i", f, f) - r * r)
        root = np.sqrt(np.where(disc >= 0, disc, np.nan))
        return (-half_b - root) / dd, (-half_b + root) / dd, d

    def crossed(self, a, b):
        t0, t1, _ = self._sphere_crossings(a, b)
        with np.errstate(invalid="ignore"):
            return (t1 > 0) & (t0 < 1)  # the segment meets the solid ball

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

    def __init__(self, n_particles, center=None, radius=None, **contact):
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

    def crossed(self, a, b):
        t0, t1, d = self._sphere_crossings(a, b)
        below = float(self.center[None][1])  # the shell is the part under the rim plane
        out = np.zeros(len(a), dtype=bool)
        with np.errstate(invalid="ignore"):
            for t in (t0, t1):
                out |= (t >= 0) & (t <= 1) & (a[:, 1] + t * d[:, 1] < below)
        return out

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


def make_terrain(kind: str, n_particles: int, geometry: dict, **contact) -> Terrain:
    """Build the terrain of ``kind`` with its geometry parameters and contact coefficients
    (keys of ``CONTACT_DEFAULTS``; missing ones take their defaults)."""
    cls = CLASSES[kind]
    return cls(n_particles, **geometry, **contact)
