"""A run's own error estimate: the same scene again at half and a quarter of the step.

With a method of order p, the difference D(h) between the runs at h and h/2 is about
(1 - 2^-p) C h^p, so the error of the run at h is D(h) 2^p / (2^p - 1) (Richardson), and
D(h) / D(h/2) is about 2^p. That holds only in the asymptotic range (the step small enough for
the leading error term to dominate; not through a chaotic or a contact-dominated stretch): the
third run measures the ratio, and where its observed order is more than ``ORDER_TOLERANCE`` from
p the estimate is withheld (``None``) rather than given as a number. Runs that agree to round-off
(a centre of mass no force moves) report their difference as the error.

Two measures, each the largest over evenly spaced samples of the run: the centre-of-mass
distance [m] and the shape difference [m] (RMS particle distance after the best rigid fit,
Kabsch's algorithm: what is left once translation and rotation are taken out).
"""

from __future__ import annotations

import math
import time

import numpy as np

ORDER_TOLERANCE = 0.5  # an observed order within this of the method's: the two runs fit it
SAMPLES = 20  # sampled times per run (each run's differences are the largest over them)


def rigid_fit_rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS distance [m] between positions ``a`` and ``b`` [n, 3] after the rotation and translation
    of ``b`` that bring it closest to ``a`` (Kabsch: the SVD of the centred cross-covariance, with
    the reflection excluded)."""
    pa = a - a.mean(axis=0)
    pb = b - b.mean(axis=0)
    u, _, vt = np.linalg.svd(pb.T @ pa)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    rot = u @ np.diag([1.0, 1.0, d]) @ vt
    return float(np.sqrt(np.mean(np.sum((pb @ rot - pa) ** 2, axis=1))))


def sample_run(sim, dt: float, total_steps: int, sample_steps: list[int]) -> tuple[np.ndarray | None, float]:
    """Positions [samples, n, 3] of ``sim`` from its start state at step ``dt`` [s] after each of
    ``sample_steps`` (increasing step counts, the last ``total_steps``), and the wall time [s];
    None if the run diverged."""
    sim.reset()
    sim.set_dt(dt)
    sim.advance(1)  # the first step of a new dt may compile: not part of the run's cost
    sim.reset()
    sim.set_dt(dt)
    out = []
    start = time.perf_counter()
    done = 0
    for k in sample_steps:
        sim.advance(k - done)
        done = k
        if sim.diverged:
            return None, time.perf_counter() - start
        out.append(sim.state.x.to_numpy().astype(np.float64))
    return np.stack(out), time.perf_counter() - start


def _sample_steps(total: int, samples: int) -> list[int]:
    every = max(1, total // samples)
    steps = list(range(every, total + 1, every))
    if not steps or steps[-1] != total:
        steps.append(total)
    return steps


def _differences(a: np.ndarray, b: np.ndarray, mass: np.ndarray) -> tuple[float, float]:
    """(largest centre-of-mass distance, largest rigid-fit RMS) [m] between two sampled runs."""
    w = mass / mass.sum()
    com = max(float(np.linalg.norm(w @ xa - w @ xb)) for xa, xb in zip(a, b))
    shape = max(rigid_fit_rms(xa, xb) for xa, xb in zip(a, b))
    return com, shape


def judge(d_h: float, d_half: float, order: int) -> tuple[float | None, float | None]:
    """(observed order or None, Richardson error estimate [m] of the run at h, or None where the
    runs do not fit ``order``) from the differences at h (runs h, h/2) and h/2 (runs h/2, h/4)."""
    if not (d_h > 0 and d_half > 0 and math.isfinite(d_h) and math.isfinite(d_half)):
        return None, None
    observed = math.log2(d_h / d_half)
    if abs(observed - order) > ORDER_TOLERANCE:
        return observed, None
    return observed, d_h * 2**order / (2**order - 1)


def estimate(sim, duration: float, order: int, samples: int = SAMPLES) -> dict:
    """The error estimate of ``sim``'s run for ``duration`` [s] at its current dt, from runs at
    dt, dt/2 and dt/4 (``sim`` is reset and left at its start state, at its dt): the largest
    differences between the dt and dt/2 runs, the observed orders, the extrapolated errors (None
    where the runs do not fit the method's ``order``) and what the three runs cost."""
    from .simulation import step_count

    dt = sim.dt
    total = step_count(duration, dt)
    steps = _sample_steps(total, samples)
    runs, walls = [], []
    for j in range(3):
        factor = 2**j
        xs, wall = sample_run(sim, dt / factor, total * factor, [k * factor for k in steps])
        walls.append(wall)
        runs.append(xs)
    sim.reset()
    sim.set_dt(dt)
    out = {"dts": [dt, dt / 2, dt / 4], "order": order, "samples": len(steps),
           "wall_seconds": walls, "cost_seconds": float(sum(walls))}
    if any(r is None for r in runs):
        out.update({"diverged": True, "com_difference": None, "shape_difference": None,
                    "observed_order_com": None, "observed_order_shape": None, "com_error": None,
                    "shape_error": None, "in_asymptotic_range": False})
        return out
    mass = sim.model.mass_np.astype(np.float64)
    # differences below this are round-off [m], not the method's error
    extent = float(np.ptp(runs[0][0], axis=0).max()) or 1.0
    round_off = 1e3 * float(np.finfo(sim.model.real).eps) * extent
    out["round_off"] = round_off
    (com_h, shape_h), (com_half, shape_half) = _differences(runs[0], runs[1], mass), _differences(runs[1], runs[2], mass)
    out["diverged"] = False
    for key, d_h, d_half in (("com", com_h, com_half), ("shape", shape_h, shape_half)):
        observed, error = judge(d_h, d_half, order)
        if d_h <= round_off:  # the runs agree to round-off: so does the run with the truth, as far as they tell
            observed, error = None, d_h
        out.update({f"{key}_difference": d_h, f"observed_order_{key}": observed, f"{key}_error": error,
                    f"{key}_round_off": d_h <= round_off})
    out["in_asymptotic_range"] = out["com_error"] is not None and out["shape_error"] is not None
    return out


def lines(est: dict) -> list[str]:
    """The estimate in words, for stdout."""
    dts = ", ".join(f"{d:g}" for d in est["dts"])
    cost = f"cost {est['cost_seconds']:.2f} s of wall time"
    if est.get("run_wall_seconds"):
        cost += f", {est['cost_seconds'] / est['run_wall_seconds']:.2g}x the run's"
    if est["diverged"]:
        return [f"error estimate: a run at a smaller step diverged; no estimate ({cost})"]
    out = [f"error estimate (runs at {dts} s, largest over {est['samples']} samples; {cost}):"]
    for key, what in (("com", "centre of mass"), ("shape", "shape (RMS after the best rigid fit)")):
        diff, err, obs = est[f"{key}_difference"], est[f"{key}_error"], est[f"observed_order_{key}"]
        if est[f"{key}_round_off"]:
            out.append(f"  {what}: dt vs dt/2 differ by {diff:.3g} m: round-off, no error to estimate")
        elif err is not None:
            out.append(f"  {what}: dt vs dt/2 differ by {diff:.3g} m; estimated error {err:.3g} m "
                       f"(observed order {obs:.2f}, the method's {est['order']})")
        else:
            out.append(f"  {what}: dt vs dt/2 differ by {diff:.3g} m; not in the asymptotic range "
                       f"(the runs do not fit order {est['order']}): no error estimate")
    return out


def legend(est: dict) -> str:
    """The estimate in one short line, for a video's overlay and a gallery caption: each measure's
    estimated error [m], or why there is none."""
    if est["diverged"]:
        return "error estimate: none (a run at a smaller step diverged)"
    if est["com_error"] is None and est["shape_error"] is None:
        return f"error estimate: none (the runs at dt/2, dt/4 do not fit order {est['order']})"
    parts = []
    for key, what in (("com", "centre of mass"), ("shape", "shape")):
        err = est[f"{key}_error"]
        if est[f"{key}_round_off"]:
            parts.append(f"{what} {err:.2g} m (round-off)")
        elif err is not None:
            parts.append(f"{what} {err:.3g} m")
        else:
            parts.append(f"{what} none (not order {est['order']})")
    return "error estimate: " + ", ".join(parts)
