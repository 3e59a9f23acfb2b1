"""Reference implementations of one semi-implicit Euler mass-spring step, for the speed study.

Both compute exactly the engine's forces for a scene without terrain (gravity, Hooke springs,
dampers along the spring) and the same update (v += dt a; x += dt v), so the comparison is like
with like:

* ``NumpyStepper``: vectorised numpy over springs, forces scattered with ``np.bincount``;
* ``WarpStepper``: NVIDIA Warp (``warp-lang``, an optional benchmark extra, never a dependency
  of the engine), written the way ``warp.sim`` does it: a spring kernel with atomic adds, then an
  integrate kernel.
"""
from typing import Any

import numpy as np


def spring_arrays(model):
    """Per-spring (a, b, rest [m], k [N/m], kd [N s/m]) and per-particle inverse mass, numpy."""
    group, pairs = model.group_np, model.pairs_np  # each a download: take them once
    k = model.group_k.to_numpy().astype(np.float64)[group]
    kd = model.group_kd.to_numpy().astype(np.float64)[group]
    inv_m = np.where(model.mass_np > 0, 1.0 / model.mass_np, 0.0)
    return pairs[:, 0], pairs[:, 1], model.rest_np, k, kd, inv_m


class NumpyStepper:
    """Semi-implicit Euler in numpy; ``step(n)`` advances ``self.x``, ``self.v`` in place."""

    def __init__(self, model, x, v, dt, dtype=np.float64):
        a, b, rest, k, kd, inv_m = spring_arrays(model)
        self.a, self.b = a, b
        self.rest, self.k, self.kd = (np.asarray(t, dtype) for t in (rest, k, kd))
        self.inv_m = np.asarray(inv_m, dtype)[:, None]
        self.g = np.asarray(model.gravity[None].to_numpy(), dtype) * (self.inv_m > 0)
        self.x = np.array(x, dtype)
        self.v = np.array(v, dtype)
        self.dt = dtype(dt)
        self.n = len(self.x)

    def forces(self) -> np.ndarray:
        d = self.x[self.a] - self.x[self.b]
        length = np.linalg.norm(d, axis=1)
        safe = np.where(length > 0, length, 1)
        l = d / safe[:, None]
        mag = self.k * (length - self.rest) + self.kd * np.einsum("ij,ij->i", self.v[self.a] - self.v[self.b], l)
        fs = np.where(length[:, None] > 0, -mag[:, None] * l, 0)
        f = np.empty_like(self.x)
        for c in range(3):
            f[:, c] = np.bincount(self.a, fs[:, c], self.n) - np.bincount(self.b, fs[:, c], self.n)
        return f

    def step(self, n: int = 1):
        for _ in range(n):
            self.v += self.dt * (self.g + self.forces() * self.inv_m)
            self.x += self.dt * self.v


def warp_available() -> bool:
    try:
        import warp  # noqa: F401
    except Exception:  # noqa: BLE001 - any import problem means "not available"
        return False
    return True


class WarpStepper:
    """Semi-implicit Euler in NVIDIA Warp on ``device`` ("cpu" or "cuda")."""

    def __init__(self, model, x, v, dt, precision="f64", device="cpu", fast_math=False):
        """``fast_math``: Warp's own ``fast_math`` module option (its fastest setting)."""
        import warp as wp

        wp.config.quiet = True
        wp.init()
        self.wp = wp
        self.device = device
        real = wp.float64 if precision == "f64" else wp.float32
        vec = wp.vec3d if precision == "f64" else wp.vec3f
        npreal = np.float64 if precision == "f64" else np.float32
        a, b, rest, k, kd, inv_m = spring_arrays(model)
        self.springs, self.integrate = _warp_kernels(fast_math)
        arr = lambda data, dtype: wp.array(np.ascontiguousarray(data), dtype=dtype, device=device)  # noqa: E731
        self.a = arr(a.astype(np.int32), wp.int32)
        self.b = arr(b.astype(np.int32), wp.int32)
        self.rest, self.k, self.kd = (arr(t.astype(npreal), real) for t in (rest, k, kd))
        self.inv_m = arr(inv_m.astype(npreal), real)
        self.x = arr(np.asarray(x, npreal), vec)
        self.v = arr(np.asarray(v, npreal), vec)
        self.f = wp.zeros(len(x), dtype=vec, device=device)
        self.g = vec(*model.gravity[None].to_numpy().astype(npreal).tolist())
        self.dt = real(dt)
        self.zero = real(0.0)
        self.n_springs, self.n = len(a), len(x)

    def step(self, n: int = 1):
        """``n`` steps: clear forces, spring kernel (atomic adds), integrate kernel (as warp.sim does)."""
        wp = self.wp
        for _ in range(n):
            self.f.zero_()
            wp.launch(self.springs, dim=self.n_springs, device=self.device,
                      inputs=[self.x, self.v, self.a, self.b, self.rest, self.k, self.kd, self.zero], outputs=[self.f])
            wp.launch(self.integrate, dim=self.n, device=self.device,
                      inputs=[self.inv_m, self.g, self.dt, self.zero, self.f], outputs=[self.x, self.v])

    def sync(self):
        self.wp.synchronize_device(self.device)

    def numpy(self):
        return self.x.numpy(), self.v.numpy()


_WARP_KERNELS = None


def _warp_kernels(fast_math=False):
    """The two Warp kernels, generic over precision (Warp builds one overload per dtype).

    The module's options are fixed when its kernels are first built: one setting per process.
    """
    global _WARP_KERNELS
    if _WARP_KERNELS is not None:
        return _WARP_KERNELS
    import warp as wp

    wp.set_module_options({"fast_math": bool(fast_math)})

    @wp.kernel
    def springs(x: wp.array(dtype=Any), v: wp.array(dtype=Any), a: wp.array(dtype=wp.int32),
                b: wp.array(dtype=wp.int32), rest: wp.array(dtype=Any), k: wp.array(dtype=Any),
                kd: wp.array(dtype=Any), zero: Any, f: wp.array(dtype=Any)):
        s = wp.tid()
        i = a[s]
        j = b[s]
        d = x[i] - x[j]
        length = wp.length(d)
        if length > zero:
            l = d / length
            fs = -(k[s] * (length - rest[s]) + kd[s] * wp.dot(v[i] - v[j], l)) * l
            wp.atomic_add(f, i, fs)
            wp.atomic_sub(f, j, fs)

    @wp.kernel
    def integrate(inv_m: wp.array(dtype=Any), g: Any, dt: Any, zero: Any, f: wp.array(dtype=Any),
                  x: wp.array(dtype=Any), v: wp.array(dtype=Any)):
        i = wp.tid()
        w = inv_m[i]
        acc = f[i] * w
        if w > zero:
            acc = acc + g
        vn = v[i] + dt * acc
        v[i] = vn
        x[i] = x[i] + dt * vn

    _WARP_KERNELS = (springs, integrate)
    return _WARP_KERNELS


class YardstickStepper:
    """The plain-Taichi yardstick (the yardstick taichi_ref.py (outside this repository; re-implemented here) --mode gather --perspring) on the
    engine's model: one fused parallel loop per step, each particle sums its springs from a CSR
    list (every spring twice), stiffness and damping read per entry from fields, ping-pong state.
    No terrain, no divergence check, constants baked in: what a plain Taichi kernel does with
    the same work. ``step(n)`` advances; ``numpy()`` -> (x, v). Needs a running Taichi."""

    def __init__(self, model, x, v, dt):
        import taichi as ti

        model.ensure_adjacency()
        n, e = model.n_particles, 2 * model.n_springs
        group = model.adj_group.to_numpy()[:e]
        self.model, self.n = model, n
        self.k, self.kd = ti.field(float, max(e, 1)), ti.field(float, max(e, 1))
        self.k.from_numpy(model.group_k.to_numpy()[group])
        self.kd.from_numpy(model.group_kd.to_numpy()[group])
        self.xs = [ti.Vector.field(3, float, n) for _ in range(2)]
        self.vs = [ti.Vector.field(3, float, n) for _ in range(2)]
        self.inv_m = np.where(model.mass_np > 0, 1.0 / model.mass_np, 0.0).astype(model.real)
        assert np.all(self.inv_m == self.inv_m[0]), "the yardstick bakes one particle mass in"
        self.dt, self.g = float(dt), tuple(float(c) for c in model.gravity[None].to_numpy())
        self.kernel = self._make_kernel()
        self.set(x, v)

    def set(self, x, v):
        self.xs[0].from_numpy(np.asarray(x, self.model.real))
        self.vs[0].from_numpy(np.asarray(v, self.model.real))
        self.cur = 0

    def _make_kernel(self):
        import taichi as ti

        m, k_, kd_ = self.model, self.k, self.kd
        n, dt, inv_m, g = self.n, self.dt, float(self.inv_m[0]), self.g

        @ti.kernel
        def step(xo: ti.template(), vo: ti.template(), xn: ti.template(), vn: ti.template()):
            for i in range(n):
                xi, vi = xo[i], vo[i]
                fi = ti.Vector([0.0, 0.0, 0.0])
                for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                    j = m.adj_other[e]
                    d = xi - xo[j]
                    length = d.norm()
                    lh = d / length
                    fi += -k_[e] * (length - m.adj_rest[e]) * lh - kd_[e] * (vi - vo[j]).dot(lh) * lh
                vnew = vi + dt * (fi * inv_m + ti.Vector(g))
                vn[i] = vnew
                xn[i] = xi + dt * vnew

        return step

    def step(self, n: int = 1):
        for _ in range(n):
            c = self.cur
            self.kernel(self.xs[c], self.vs[c], self.xs[1 - c], self.vs[1 - c])
            self.cur = 1 - c

    def numpy(self):
        return self.xs[self.cur].to_numpy(), self.vs[self.cur].to_numpy()
