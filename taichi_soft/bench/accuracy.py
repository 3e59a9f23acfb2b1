"""Work-precision: error against cost for each integrator over a sweep of time steps.

Error is the RMS particle position error [m] against a reference solution (RK4, f64, fast math
off, at a step 10 times smaller than the smallest swept), at the final time and over the whole
trajectory (sampled at ``frames`` evenly spaced times). Cost is wall time (warm-up first,
``ti.sync()``, minimum of repeats: ``timing.time_one``) and, independent of the machine, force evaluations.
"""
from __future__ import annotations

import json
import math

import numpy as np

from ..sim.scene import load_scene
from ..sim.simulation import Simulation
from ..timing import time_one

# The two cases of the work-precision study: (scene, overrides, end time [s]).
CASES = {
    # smooth, no contact: shows each method's true order
    "smooth": ("free_float", ["body.0.n=5", "body.0.size=2.0"], 0.2),
    # the default drop onto the plane, what users actually see (contact makes it non-smooth)
    # (impact at t = 0.71 s, then a bounce)
    "drop": ("plane", ["body.0.n=5", "body.0.size=2.0", "body.0.center=[0, 2.5, 0]"], 1.0),
}


def trajectory(sim: Simulation, t_end: float, frames: int) -> tuple[np.ndarray, bool]:
    """Positions at ``frames`` + 1 evenly spaced times in [0, t_end] -> [frames + 1, particles, 3]."""
    steps_total = int(round(t_end / sim.dt))
    per = steps_total // frames
    if per * frames != steps_total:
        raise ValueError("dt must divide the frame interval")
    out = [sim.state.x.to_numpy()]
    for _ in range(frames):
        sim.advance(per)
        if sim.diverged:
            return np.stack(out), True
        out.append(sim.state.x.to_numpy())
    return np.stack(out), False


def step_sizes(t_end: float, frames: int, dt_max: float, count: int, ratio: float = 2.0) -> list[float]:
    """Log-spaced steps that divide the frame interval exactly, largest <= dt_max."""
    interval = t_end / frames
    out = []
    m = max(1, math.ceil(interval / dt_max - 1e-9))
    while len(out) < count:
        dt = interval / m
        if not out or dt < out[-1] / (ratio * 0.9):
            out.append(dt)
        m += 1
    return out


def run_case(case: str, sweeps: dict, frames: int = 10, repeats: int = 3, progress=None) -> tuple[list[dict], bool]:
    """Errors and costs of every (integrator, dt) in ``sweeps`` = {integrator: [dt, ...]} on ``case``.

    One reference for all: RK4 at a step 10 times smaller than the smallest swept. Returns
    ``(rows, interrupted)``; Ctrl-C stops the sweep and returns the rows measured so far.
    (``bench`` runs the same pieces, ``reference`` and ``measure_integrator``, as separate tasks.)
    """
    ref, dt_ref = reference(case, min(min(d) for d in sweeps.values()), frames)
    rows = []
    total = sum(len(d) for d in sweeps.values())
    try:
        for name, dts in sweeps.items():
            rows.extend(measure_integrator(case, name, dts, ref, dt_ref, frames, repeats, progress, len(rows), total))
    except KeyboardInterrupt:
        return rows, True
    return rows, False


def reference(case: str, dt_min: float, frames: int = 10) -> tuple[np.ndarray, float]:
    """RK4 trajectory [frames + 1, particles, 3] of ``case`` at a step dividing the frame interval,
    at most ``dt_min / 10`` [s]; returns (trajectory, its dt)."""
    scene_name, sets, t_end = CASES[case]
    m_ref = math.ceil((t_end / frames) / (dt_min / 10))
    ref_sim = Simulation(load_scene(scene_name, sets), integrator="rk4", dt=(t_end / frames) / m_ref)
    ref, _ = trajectory(ref_sim, t_end, frames)
    return ref, ref_sim.dt


def measure_integrator(case: str, name: str, dts, ref, dt_ref: float, frames: int = 10, repeats: int = 3,
                       progress=None, done: int = 0, total: int = 0) -> list[dict]:
    """One row per dt of ``name`` on ``case`` against the reference trajectory ``ref``."""
    scene_name, sets, t_end = CASES[case]
    sim = Simulation(load_scene(scene_name, sets), integrator=name, dt=dts[0])
    sim.advance(1)  # warm-up: Taichi compiles on the first call
    rows = []
    for dt in dts:
        rows.append(_measure(sim, case, name, dt, t_end, frames, repeats, ref, dt_ref))
        if progress:
            progress(done + len(rows), total, f"{case} {name} dt={dt:.2e}")
    return rows


def _measure(sim, case, name, dt, t_end, frames, repeats, ref, dt_ref) -> dict:
    def setup():
        sim.reset()
        sim.set_dt(dt)
        sim.integrator.stats()  # start the solver counters afresh

    # the minimum of the repeats (the least disturbed run), not the median
    t = time_one(lambda: trajectory(sim, t_end, frames), repeats, setup=setup, done=lambda r: r[1])
    best, (traj, diverged) = t.min, t.last
    steps = int(round(t_end / dt))
    stats = sim.integrator.stats()
    row = {"case": case, "integrator": name, "dt": dt, "steps": steps, "wall_s": best, "diverged": diverged,
           "force_evals": steps * sim.integrator.spring_passes_per_step(stats), "dt_reference": dt_ref,
           "solver_stats": json.dumps(stats), "error_final": math.nan, "error_trajectory": math.nan}
    if not diverged:
        diff = traj - ref
        row["error_final"] = float(np.sqrt(np.mean(np.sum(diff[-1] ** 2, axis=-1))))
        row["error_trajectory"] = float(np.sqrt(np.mean(np.sum(diff ** 2, axis=-1))))
    return row


def fitted_order(rows: list[dict], integrator: str, floor: float = 1e-11) -> float | None:
    """Least-squares slope of log(final error) against log(dt) over converged, above-rounding points."""
    pts = [(r["dt"], r["error_final"]) for r in rows
           if r["integrator"] == integrator and not r["diverged"] and r["error_final"] > floor]
    if len(pts) < 2:
        return None
    x = np.log([p[0] for p in pts])
    y = np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])
