"""The view ray against the drawn surface, on the device: one kernel launch per press.

``picking.pick_surface`` does the same in numpy, but needs the positions read back first, which
is most of a press's time (docs/decisions/device-side-pick.md). Here the positions stay in their
field: every triangle is tested in parallel (Moller-Trumbore), the nearest hit is kept by an
atomic minimum (then the first triangle at that distance), and the triangle's corner nearest the
hit point is the answer. Same result as ``pick_surface`` (tests/test_demo.py compares them).
"""
import numpy as np
import taichi as ti

NONE = -1  # no triangle crossed
_FAR = 1e300  # [m] the atomic minimum's start: no crossing yet


@ti.data_oriented
class SurfacePicker:
    """Picks on the surfaces of ``model``'s bodies (their ``surface`` triangles, particle indices)."""

    def __init__(self, model):
        tri = np.concatenate([np.reshape(b.surface, (-1, 3)) for b in model.bodies]).astype(np.int32)
        self.model = model
        self.n_triangles = len(tri)
        self.tri = ti.Vector.field(3, ti.i32, max(self.n_triangles, 1))
        self.tri.from_numpy(tri if len(tri) else np.zeros((1, 3), np.int32))
        self.t_min = ti.field(ti.f64, ())  # nearest crossing [m]
        self.k_min = ti.field(ti.i32, ())  # the first triangle crossed there

    def pick(self, x, origin, direction) -> tuple[int, np.ndarray] | None:
        """(particle, its position [m]) of the surface the ray (``origin`` [m], unit ``direction``)
        hits first, at the positions ``x`` (a vec3 field [m]); None if it crosses no triangle."""
        r = self._k_pick(x, *(float(c) for c in origin), *(float(c) for c in direction))
        return None if r[0] < 0 else (int(r[0]), np.array([r[1], r[2], r[3]], dtype=np.float64))

    @ti.func
    def _hit(self, x: ti.template(), k, o, d):
        """Distance along the ray [m] at which it crosses triangle k (Moller-Trumbore), or -1."""
        a = ti.cast(x[self.tri[k][0]], ti.f64)
        e1 = ti.cast(x[self.tri[k][1]], ti.f64) - a
        e2 = ti.cast(x[self.tri[k][2]], ti.f64) - a
        p = d.cross(e2)
        det = e1.dot(p)
        out = -1.0
        if ti.abs(det) > 1e-12:
            inv = 1.0 / det
            s = o - a
            u = s.dot(p) * inv
            q = s.cross(e1)
            v = d.dot(q) * inv
            t = e2.dot(q) * inv
            if u >= 0 and v >= 0 and u + v <= 1 and t > 0:
                out = t
        return out

    @ti.kernel
    def _k_pick(self, x: ti.template(), ox: ti.f64, oy: ti.f64, oz: ti.f64, dx: ti.f64, dy: ti.f64,
                dz: ti.f64) -> ti.types.vector(4, ti.f64):
        # (particle index or NONE, its position): one launch returns both. Two passes: the nearest
        # distance, then the first triangle at exactly it (recomputed the same way), as numpy's argmin.
        o = ti.Vector([ox, oy, oz])
        d = ti.Vector([dx, dy, dz])
        self.t_min[None] = _FAR
        self.k_min[None] = self.n_triangles
        for k in range(self.n_triangles):
            t = self._hit(x, k, o, d)
            if t > 0:
                ti.atomic_min(self.t_min[None], t)
        for k in range(self.n_triangles):
            if self._hit(x, k, o, d) == self.t_min[None]:
                ti.atomic_min(self.k_min[None], k)
        out = NONE
        pos = ti.Vector.zero(ti.f64, 3)
        k = self.k_min[None]
        if k < self.n_triangles:
            at = o + self.t_min[None] * d
            best2 = 1e300
            for c in ti.static(range(3)):
                j = self.tri[k][c]
                r = ti.cast(x[j], ti.f64) - at
                if r.dot(r) < best2:
                    best2 = r.dot(r)
                    out = j
            pos = ti.cast(x[out], ti.f64)
        return ti.Vector([ti.cast(out, ti.f64), pos[0], pos[1], pos[2]])
