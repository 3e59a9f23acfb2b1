"""Linear stability limits of the integrators on a scene: the largest step each method takes.

Linearised about the rest shape, the springs and dampers are x'' = -M^-1 K x - M^-1 C x' with
K = sum_s k_s l_s l_s^T and C = sum_s kd_s l_s l_s^T over the springs' (a, b) blocks. Each mode
(an eigenvector of M^-1 K, eigenvalue w2) is the oscillator J = [[0, 1], [-w2, -c w2]], with c
the damper-to-stiffness ratio kd/k of its springs (K and C are proportional when all groups share
one ratio, as in the shipped scenes). A step h of a method maps a mode's (x, v) by its
amplification matrix A(h, J); the step is stable when A's spectral radius is at most 1 for every
mode. The largest w2 comes from power iteration on M^-1/2 K M^-1/2; the modes between are
sampled (a method's region need not bind at the stiffest mode), each with the smallest and the
largest ratio c in the scene.

Used by the divergence hint (cli ``run``): a step below the diverged method's limit, and the
methods that take the requested step. Checked against runs in tests/test_stability_hint.py.
"""

from __future__ import annotations

import math

import numpy as np

from .base import REGISTRY

# One step of each explicit method maps a mode (x, v) of J = [[0, 1], [-w2, -g]] by its
# amplification matrix, which each integrator class declares (``Integrator.amplification``): a
# method carrying more state than (x, v) maps all of it. These are the shipped methods' matrices.


def taylor(order):
    """Explicit Runge-Kutta of ``order`` stages = order: the degree-``order`` Taylor polynomial of h J."""
    def amplification(h, jac):
        a = np.eye(2)
        term = np.eye(2)
        for k in range(1, order + 1):
            term = term @ (h * jac) / k
            a = a + term
        return a
    return amplification


def symplectic_euler(h, jac):
    """v1 = v + h (J x) ; x1 = x + h v1 (``semi_implicit_euler``)."""
    w2, g = -jac[1, 0], -jac[1, 1]
    return np.array([[1 - h * h * w2, h * (1 - h * g)], [-h * w2, 1 - h * g]])


def velocity_verlet(h, jac):
    """One step of ``velocity_verlet`` on the state (x, v, a) it carries (a: the last force):
    vh = v + h/2 a, x1 = x + h vh; a first force a0 = J (x1, vh + h/2 a) at the predicted
    velocity; the damper-only corrector re-predicts v1 = vh + h/2 a0 and takes the damper there,
    a1 = J (x1, vh + h/2 a0); v1 = vh + h/2 a1. A 3 x 3 matrix: the carried force is a state of
    the method."""
    w2, g = -jac[1, 0], -jac[1, 1]
    x1 = np.array([1.0, h, h * h / 2])
    vh = np.array([0.0, 1.0, h / 2])
    a0 = -w2 * x1 - g * (vh + np.array([0.0, 0.0, h / 2]))
    a1 = -w2 * x1 - g * (vh + (h / 2) * a0)
    v1 = vh + (h / 2) * a1
    return np.array([x1, v1, a1])


def stiffest_w2(x0: np.ndarray, mass: np.ndarray, pairs: np.ndarray, k: np.ndarray, iterations: int = 100) -> float:
    """Largest eigenvalue [1/s^2] of M^-1 K at shape ``x0`` [n, 3] (masses [n] kg, springs
    ``pairs`` [s, 2] of stiffness ``k`` [s] N/m); particles of mass <= 0 are pinned (excluded)."""
    free = mass > 0
    inv_sqrt_m = np.where(free, 1.0 / np.sqrt(np.where(free, mass, 1.0)), 0.0)
    a, b = pairs[:, 0], pairs[:, 1]
    d = x0[a] - x0[b]
    length = np.linalg.norm(d, axis=1)
    keep = length > 0
    a, b, k = a[keep], b[keep], k[keep]
    l = d[keep] / length[keep, None]
    n = len(mass)

    def apply(v):  # (M^-1/2 K M^-1/2) v
        w = v * inv_sqrt_m[:, None]
        f = (k * np.einsum("ij,ij->i", l, w[a] - w[b]))[:, None] * l
        out = np.stack([np.bincount(a, f[:, c], n) - np.bincount(b, f[:, c], n) for c in range(3)], axis=1)
        return out * inv_sqrt_m[:, None]

    v = np.random.default_rng(0).standard_normal((n, 3)) * free[:, None]
    w2 = 0.0
    for _ in range(iterations):
        norm = np.linalg.norm(v)
        if norm == 0:
            return 0.0
        v = v / norm
        av = apply(v)
        w2 = float(np.sum(v * av))
        v = av
    return w2


def is_stable(name: str, h: float, w2_max: float, ratios: tuple[float, float], samples: int = 200) -> bool:
    """Whether ``name`` at step ``h`` [s] is linearly stable on every mode up to ``w2_max``."""
    amp = REGISTRY[name].amplification
    for w2 in w2_max * np.geomspace(1e-4, 1.0, samples):
        for c in ratios:
            jac = np.array([[0.0, 1.0], [-w2, -c * w2]])
            if np.max(np.abs(np.linalg.eigvals(amp(h, jac)))) > 1.0 + 1e-9:
                return False
    return True


def stable_limit(name: str, w2_max: float, ratios: tuple[float, float]) -> float | None:
    """Largest stable step [s] of ``name`` (bisection, 0.5 % resolution); inf for the implicit
    methods (backward Euler is A-stable); None for a method this module does not know; 0 if no
    step is stable."""
    cls = REGISTRY.get(name)
    if cls is None:
        return None
    if cls.implicit or w2_max <= 0:
        return math.inf
    lo, hi = 0.0, 4.0 / math.sqrt(w2_max)  # no explicit method here is stable at h w = 4
    while hi - lo > 0.005 * hi:
        mid = 0.5 * (lo + hi)
        if is_stable(name, mid, w2_max, ratios):
            lo = mid
        else:
            hi = mid
    # Below h w = 1e-3 only the growth tolerance is met (explicit Euler without dampers grows by
    # 1 + (h w)^2 / 2 per step at any h): no step is stable.
    return lo if lo * math.sqrt(w2_max) > 1e-3 else 0.0


def scene_modes(model) -> tuple[float, tuple[float, float]]:
    """(w2_max [1/s^2], (smallest, largest) kd/k ratio [s]) of a ``Model`` at its start shape."""
    k_groups = model.group_k.to_numpy()[: model.n_groups].astype(np.float64)
    kd_groups = model.group_kd.to_numpy()[: model.n_groups].astype(np.float64)
    group = model.group_np
    w2 = stiffest_w2(model.x0_np.astype(np.float64), model.mass_np.astype(np.float64), model.pairs_np,
                     k_groups[group])
    used = np.unique(group)
    ratios = kd_groups[used] / k_groups[used]
    return w2, (float(ratios.min()), float(ratios.max()))


def round_down(h: float, digits: int = 2) -> float:
    """``h`` rounded down to ``digits`` significant digits (0.002437 -> 0.0024)."""
    exp = math.floor(math.log10(h)) - digits + 1
    return math.floor(h / 10**exp) * 10**exp


SAFETY = 0.8  # the hint's fraction of the linear limit: contact and large deformations lower the real one


def divergence_hint(model, name: str, dt: float) -> tuple[float, str]:
    """(a step [s] to try, one sentence naming it and the methods that take ``dt``) after ``name``
    diverged at step ``dt`` [s] on ``model``. The step is SAFETY times the method's linear limit;
    half of ``dt`` if the method has no estimate or ``dt`` was already below that step (then
    something else than the springs' linear modes set the limit)."""
    w2, ratios = scene_modes(model)
    limit = stable_limit(name, w2, ratios)
    limits = {other: stable_limit(other, w2, ratios) for other in REGISTRY}
    takers = [other for other, lim in limits.items() if other != name and lim is not None and lim > dt / SAFETY]
    take = f"; {' or '.join(takers)} would take dt = {dt:g} s" if takers else ""
    if limit is None or not 0 < limit < math.inf or round_down(SAFETY * limit) >= dt:
        hint = round_down(dt / 2)
        return hint, f"try --dt {hint:g}{take}"
    hint = round_down(SAFETY * limit)
    return hint, (f"its linear stability limit for this scene is about {limit * 1e3:.2g} ms (stiffest spring mode, "
                  f"{math.sqrt(w2):.0f} rad/s): try --dt {hint:g}{take}")
