"""Work-precision at equal error: which family is cheaper for a given accuracy, per stiffness.

Cases (a cube of ``n``^3 particles, edge ``size`` [m], 1 kg per particle, default springs scaled by
the stiffness factor, the scenes' contact: restitution 0.8, mu 0.3):

* ``flat``: dropped flat onto the plane (its bottom ``DROP`` m above), not chaotic: trajectory errors;
* ``slide``: face down on the 45-degree plane, released at rest: it slides (mu < 1); trajectory errors;
* ``ensemble``: ``len(ENSEMBLE)`` tilted drops onto the plane. Corner impacts of a stiff cube are
  chaotic (no method converges to one trajectory), so only distributions are compared: first
  bounce apex, rest height and time to rest, their means over the members.

Methods and steps: every explicit method from 0.9 x its linear stable limit
(``integrators.linear_stability``; contact may lower the real one, a diverged run is recorded as such)
halving; both implicit solvers from 1/15 s halving to about 1 ms, at the tolerances of ``TOLERANCES``.
Reference: RK4 at 1/64 of its linear stable limit, self-checked against 1/32 (the self-check is
in the references' CSV and table: errors below it are not resolved).

Errors [m]: ``com_error`` the largest distance between the centre of mass and the reference's
over the frames (every ``FRAME`` s); ``shape_error`` the largest RMS particle offset after the
best rigid fit (Kabsch) onto the reference's particles, i.e. in the body frame; ``apex`` the
centre of mass's first bounce apex above the plane [m] (the highest sample after the first
lowest one); ``rest_height`` [m] its height at the end; ``rest_time`` [s] the first frame from
which its speed stays below ``REST_SPEED``. Each run samples the centre of mass every
max(dt, ``SAMPLE``) s. For ``ensemble`` the error is the largest of |mean apex - reference's| and
|mean rest height - reference's| (apex left out where the reference has none within the run).

Costs: ``wall_per_sim_s`` wall seconds per simulated second (after a warm-up, ``ti.sync()``, the
median of ``REPEATS`` runs in long launches without readbacks, not interleaved across methods;
errors come from a further, sampled run of the same steps), and ``spring_passes``, a count
independent of the machine: passes over all springs (force or gradient evaluations, Hessian
products, line-search trials) per run, from the solvers' own counters.

The verdict (fronts, cost at equal error, Markdown) is ``verdict.py``.
"""
from __future__ import annotations

import math

import numpy as np

from ..sim.error_estimate import rigid_fit_rms
from ..timing import time_one

SAMPLE = 1.0 / 240.0  # [s] centre-of-mass sampling interval (every implicit step divides or is a multiple of it)
FRAME = 1.0 / 15.0  # [s] frames at which trajectories are compared (a multiple of every step swept)
REST_SPEED = 0.1  # [m/s] centre-of-mass speed below which the body counts as at rest
DROP = {"flat": 2.0, "ensemble": 1.0}  # [m] lowest particle above the plane at the start (quick: 0.5)
STIFFNESS = (1.0, 10.0, 100.0, 1000.0)
ERRORS = (0.02, 0.05, 0.20)  # [m] equal-error levels of the verdict
WIN_MARGIN = 1.1  # implicit wins at an error when the best explicit costs at least this much more
IMPLICIT_STEPS = tuple(1.0 / m for m in (15, 30, 60, 120, 240, 480, 960))  # [s]
QUICK_IMPLICIT_STEPS = tuple(1.0 / m for m in (15, 60, 240))
EXPLICIT_HALVINGS, QUICK_EXPLICIT_HALVINGS = 5, 2  # steps per explicit sweep: 0.9 limit, /2, /4, ...
TOLERANCES = {  # label -> implicit solver options: tolerances (residual [m/s^2], iteration cap, velocity stop [m/s]), scheme
    "default": {},
    "tight": {"implicit_euler": {"newton_tol": 1e-3, "newton_iters": 100, "velocity_tol": 0.0},
              "fast_mass_spring": {"tol": 1e-3, "iterations": 200, "velocity_tol": 0.0}},
    "bdf2": {"implicit_euler": {"scheme": "bdf2"}, "fast_mass_spring": {"scheme": "bdf2"}},
    "sdirk2": {"implicit_euler": {"scheme": "sdirk2"}, "fast_mass_spring": {"scheme": "sdirk2"}},
}
# --quick (the test of the machinery): one method per family, default tolerances, two stiffnesses
QUICK_METHODS = ("semi_implicit_euler", "fast_mass_spring")
QUICK_STIFFNESS = (1.0, 1000.0)
QUICK_TOLERANCES = ("default",)
ENSEMBLE = (((1, 0, 1), 30.0), ((1, 0, 0), 20.0), ((0, 0, 1), 40.0), ((1, 1, 0), 25.0), ((0, 1, 1), 35.0))
PLANE_Y = -1.0
REPEATS = 3  # timed runs per configuration (median); --quick: 1
REFERENCE_FRACTION = 64  # the reference RK4 runs at 1/64 of its linear limit, checked against 1/32


def cube_sets(quick: bool) -> list[str]:
    n, size = (3, 1.0) if quick else (4, 2.0)
    return [f"body.0.n={n}", f"body.0.size={size}", "body.0.particle_mass=1.0"]


def case_runs(case: str, quick: bool) -> list[tuple[str, list[str], float]]:
    """(scene, overrides, end time [s]) of each run of ``case`` (one, or the ensemble's members)."""
    sets = cube_sets(quick)
    size = float(sets[1].split("=")[1])
    drop = {k: 0.5 if quick else v for k, v in DROP.items()}
    height = PLANE_Y + drop["flat"] + size / 2
    if case == "flat":
        return [("plane", sets + [f"body.0.center=[0, {height}, 0]", "body.0.rotation.degrees=0"], 0.6 if quick else 2.0)]
    if case == "slide":  # face down on the plane of normal (1, 1, 0)/sqrt 2 through the origin, 1 cm above it
        c = (size / 2 + 0.01) / math.sqrt(2)
        return [("tilted_plane", sets + [f"body.0.center=[{c}, {c}, 0]", "body.0.rotation={axis = [0, 0, 1], degrees = -45}"],
                 0.4 if quick else 1.0)]
    if case == "ensemble":
        members = ENSEMBLE[:2] if quick else ENSEMBLE
        # tilted: lift the centre by the half-diagonal so no corner starts below DROP
        lift = PLANE_Y + drop["ensemble"] + size * math.sqrt(3) / 2
        return [("plane", sets + [f"body.0.center=[0, {lift}, 0]",
                                  f"body.0.rotation={{axis = [{a[0]}, {a[1]}, {a[2]}], degrees = {d}}}"], 0.6 if quick else 2.0)
                for a, d in members]
    raise ValueError(case)


CASES = ("flat", "slide", "ensemble")


# -- one run -------------------------------------------------------------------------------------------
def build(scene: str, sets: list[str], name: str, options: dict | None = None):
    from ..sim.integrators import names
    from ..sim.scene import load_scene
    from ..sim.simulation import Simulation

    return Simulation(load_scene(scene, sets, integrator_names=names()), name, 1e-3, options=options or {})


def set_stiffness(sim, scale: float, base_k):
    """Every spring group's stiffness = base x ``scale`` (dampers unchanged), as bench stability does
    (through the model, which tells the integrator: fast_mass_spring refactorises)."""
    sim.model.set_group_stiffness(base_k[: sim.model.n_groups] * scale)


def stable_limit(sim, name: str) -> float:
    """Linear stable step [s] of explicit ``name`` on the simulation's model at its current stiffness."""
    from ..sim.integrators.linear_stability import scene_modes, stable_limit as limit

    w2, ratios = scene_modes(sim.model)
    return limit(name, w2, ratios)


def divide(dt: float, interval: float = SAMPLE) -> float:
    """The largest step <= ``dt`` that divides ``interval`` [s] (or a multiple of it, for dt > interval)."""
    if dt >= interval:
        return interval * math.floor(dt / interval + 1e-9)
    return interval / math.ceil(interval / dt - 1e-9)


def trajectory(sim, dt: float, t_end: float, repeats: int = 1) -> dict:
    """Run from the scene's start: ``repeats`` times timed in long launches without readbacks (the
    median wall time [s], ``ti.sync()`` around each; the solver stats of the first), then once
    sampled (the centre of mass every max(dt, SAMPLE) s, particles every FRAME): the same
    deterministic steps, so the samples are the timed runs' states."""
    total = int(round(t_end / dt))
    stats = []

    def setup():
        sim.reset()
        sim.set_dt(dt)
        sim.integrator.stats()

    def done(_):
        stats.append(sim.integrator.stats())
        return sim.diverged

    t = time_one(lambda: sim.advance(total), repeats, setup=setup, done=done)
    wall, stats, diverged = float(np.median(t.wall)), stats[0], sim.diverged
    sim.reset()
    sim.set_dt(dt)
    per = max(1, int(round(SAMPLE / dt)))
    frame_every = int(round(FRAME / dt))
    x = sim.state.x.to_numpy()
    com, frames, times = [x.mean(axis=0)], [x], [0.0]
    done = 0
    while done < total and not diverged:
        n = min(per, total - done)
        sim.advance(n)
        done += n
        if sim.diverged:
            diverged = True
            break
        x = sim.state.x.to_numpy()
        com.append(x.mean(axis=0))
        times.append(done * dt)
        if done % frame_every == 0:
            frames.append(x)
    sim.integrator.stats()  # the sampled run's counters are the timed run's again: drop them
    return {"times": np.array(times), "com": np.array(com), "frames": np.array(frames), "wall_s": wall,
            "diverged": diverged, "steps": total, "stats": stats}


def first_apex(times, heights) -> float:
    """Height of the first maximum after the first minimum [m] (nan if none inside the run)."""
    rising = np.flatnonzero(np.diff(heights) > 0)
    if rising.size == 0:
        return math.nan
    low = int(rising[0])
    top = low + int(np.argmax(heights[low:]))
    return float(heights[top]) if top < len(heights) - 1 else math.nan


def rest_time(times, com) -> float:
    """First time [s] from which the centre of mass's speed (over FRAME) stays below REST_SPEED (nan if never)."""
    step = max(1, int(round(FRAME / (times[1] - times[0])))) if len(times) > 1 else 1
    t, c = times[::step], com[::step]
    if len(t) < 2:
        return math.nan
    speed = np.linalg.norm(np.diff(c, axis=0), axis=1) / np.diff(t)
    moving = np.flatnonzero(speed >= REST_SPEED)
    if moving.size == 0:
        return 0.0
    last = int(moving[-1]) + 1
    return float(t[last]) if last < len(t) - 1 else math.nan


def summary(run: dict) -> dict:
    """Distribution quantities of one run: apex [m], rest height [m], rest time [s]."""
    h = run["com"][:, 1] - PLANE_Y
    return {"apex": first_apex(run["times"], h), "rest_height": float(h[-1]), "rest_time": rest_time(run["times"], run["com"])}


def compare(run: dict, ref: dict) -> dict:
    """Trajectory errors [m] of ``run`` against ``ref`` at the common frames."""
    k = min(len(run["frames"]), len(ref["frames"]))
    if run["diverged"] or k < len(ref["frames"]):
        return {"com_error": math.nan, "shape_error": math.nan}
    com = np.linalg.norm(run["frames"].mean(axis=1) - ref["frames"].mean(axis=1), axis=1).max()
    shape = max(rigid_fit_rms(b, a) for a, b in zip(run["frames"], ref["frames"]))  # a onto b
    return {"com_error": float(com), "shape_error": float(shape)}


def spring_passes(name: str, run: dict, n_springs: int) -> float:
    """Passes over all springs x springs of ``run`` (``Integrator.spring_passes_per_step``)."""
    from ..sim.integrators import REGISTRY

    return float(REGISTRY[name].spring_passes_per_step(run["stats"]) * run["steps"] * n_springs)


# -- tasks ---------------------------------------------------------------------------------------------
def _task_runtime():
    """Inside a task's fresh process: the runtime of every study (CPU, f64), as ``sweeps._task_runtime``
    (not imported from there: sweeps imports this module)."""
    from .. import runtime

    runtime.init("cpu", "f64")


def reference_task(case: str, scale: float, quick: bool) -> dict:
    """RK4 at 1/32 and 1/64 of its linear limit for every run of ``case``: the reference runs at
    1/64 (stored: frames, summaries), the self-check = the 1/32 run's differences from it. (The
    issue asked for 1/16 checked against 1/32; at x1000 those differed by 1.7 cm on the quick flat
    drop, so both are halved once more.)"""
    _task_runtime()
    out = {"case": case, "stiffness_scale": scale, "members": [], "self_check": {}}
    checks = []
    for scene, sets, t_end in case_runs(case, quick):
        sim = build(scene, sets, "rk4")
        base = sim.model.group_k.to_numpy().copy()
        set_stiffness(sim, scale, base)
        lim = stable_limit(sim, "rk4")
        coarse = trajectory(sim, divide(lim / REFERENCE_FRACTION * 2), t_end)
        fine = trajectory(sim, divide(lim / REFERENCE_FRACTION), t_end)
        out["members"].append({"frames": fine["frames"], "summary": summary(fine), "dt": divide(lim / REFERENCE_FRACTION),
                               "diverged": fine["diverged"]})
        checks.append({**compare(coarse, fine), **{f"{k}_diff": abs(a - b) for (k, a), b in
                                                   zip(summary(coarse).items(), summary(fine).values())}})
    out["self_check"] = {k: float(np.nanmax([c[k] for c in checks])) for k in checks[0]}
    out["dt"] = out["members"][0]["dt"]
    return out


def method_task(case: str, name: str, tolerance: str, scales, refs: dict, quick: bool) -> list[dict]:
    """One row per (stiffness, step) of ``name`` on ``case`` (one compile: stiffness and steps are
    fields); the wall time is the median of REPEATS timed runs (1 with ``quick``), not interleaved
    with other methods (each task is its own process)."""
    repeats = 1 if quick else REPEATS
    from ..sim.integrators import REGISTRY

    _task_runtime()
    implicit = REGISTRY[name].implicit
    options = TOLERANCES[tolerance].get(name, {}) if implicit else {}
    runs = case_runs(case, quick)
    sims = [build(scene, sets, name, options) for scene, sets, _ in runs]
    rows = []
    for sim, (_, _, t_end) in zip(sims, runs):
        trajectory(sim, 1e-3 if implicit else 1e-4, 0.01)  # warm-up: compile every kernel a run uses
    for scale in scales:
        ref = refs[f"{case}/{scale:g}"]
        bases = [s.model.group_k.to_numpy().copy() for s in sims]
        for sim, base in zip(sims, bases):
            set_stiffness(sim, scale, base)
        if implicit:
            dts = list(QUICK_IMPLICIT_STEPS if quick else IMPLICIT_STEPS)
            limit = math.inf
        else:
            limit = stable_limit(sims[0], name)
            first = divide(0.9 * limit)
            dts = [divide(first / 2**k) for k in range(QUICK_EXPLICIT_HALVINGS if quick else EXPLICIT_HALVINGS)]
        for dt in dts:
            member_rows = []
            for sim, (scene, sets, t_end), member in zip(sims, runs, ref["members"]):
                run = trajectory(sim, dt, t_end, repeats)
                err = compare(run, member) if case != "ensemble" else {}
                member_rows.append({"run": run, "err": err, "summary": summary(run) if not run["diverged"] else None,
                                    "t_end": t_end})
            rows.append(_row(case, name, tolerance if implicit else "-", scale, dt, limit, member_rows, ref, sims[0]))
        for sim, base in zip(sims, bases):
            set_stiffness(sim, 1.0, base)
    return rows


def _row(case, name, tolerance, scale, dt, limit, members, ref, sim) -> dict:
    diverged = any(m["run"]["diverged"] for m in members)
    wall = sum(m["run"]["wall_s"] for m in members)
    sim_time = sum(m["t_end"] for m in members)
    n_springs = sim.model.n_springs
    passes = sum(spring_passes(name, m["run"], n_springs) for m in members)
    s = members[0]["run"]["stats"]
    row = {"case": case, "integrator": name, "tolerance": tolerance, "stiffness_scale": scale, "dt": dt,
           "dt_over_limit": dt / limit if math.isfinite(limit) else None, "diverged": diverged,
           "wall_per_sim_s": wall / sim_time, "spring_passes_per_sim_s": passes / sim_time,
           "failed_solve_steps": sum(int(m["run"]["stats"].get("failed_solve_steps", 0)) for m in members),
           "energy_clamped_steps": sum(int(m["run"]["stats"].get("energy_clamped_steps", 0)) for m in members),
           "unconverged_steps": sum(int(m["run"]["stats"].get("unconverged_steps", 0)) for m in members),
           "final_residual_m_s2": s.get("final_residual_m_s2")}
    if diverged:
        row.update(error=math.nan)
        return row
    if case == "ensemble":
        got = {k: np.nanmean([m["summary"][k] for m in members]) for k in ("apex", "rest_height", "rest_time")}
        want = {k: np.nanmean([m["summary"][k] for m in ref["members"]]) for k in ("apex", "rest_height", "rest_time")}
        for k in got:
            row[f"mean_{k}"] = float(got[k])
            row[f"ref_mean_{k}"] = float(want[k])
            row[f"std_{k}"] = float(np.nanstd([m["summary"][k] for m in members]))
        # quantities the reference has (a soft cube may not bounce within the run: no apex); one the
        # reference has and the run lacks makes the run's error infinite (off every front)
        diffs = [abs(got[k] - want[k]) if math.isfinite(got[k]) else math.inf
                 for k in ("apex", "rest_height") if math.isfinite(want[k])]
        row["error"] = float(max(diffs)) if diffs else math.nan
    else:
        e = members[0]["err"]
        row.update(com_error=e["com_error"], shape_error=e["shape_error"], error=e["com_error"],
                   apex=members[0]["summary"]["apex"], ref_apex=ref["members"][0]["summary"]["apex"],
                   rest_time=members[0]["summary"]["rest_time"])
    return row
