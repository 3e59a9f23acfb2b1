"""The benchmark sweeps run as tasks: accuracy (work-precision), precision (work-precision at
equal error, ``bench/precision.py``) and stability (largest stable dt), with the writers of their
CSVs and plots.

Each sweep's runs are independent tasks (``taichi_soft.tasks``: each in a fresh process,
``--workers N`` local processes or a Dask ``--scheduler``); their wall-time columns are measured
under whatever else runs at the same time, so publish timings from ``--workers 1`` on a quiet
machine. A sweep interrupted with Ctrl-C stops and still returns what it measured, marked as
interrupted; a task that failed twice is listed as failed.
"""
from __future__ import annotations

import math
import statistics
from pathlib import Path

from ..sim.integrators import REGISTRY
from . import accuracy, stability
from .files import write_csv
from ..timing import time_one


TERRAINS = ("plane", "tilted_plane", "sphere", "bowl")
DT_LO = 2.5e-4  # [s] lower end of each bisection: every method here is stable at it on the default cube


def _sweep(tasks, executor, label):
    """Run ``tasks`` on ``executor`` -> (rows in task order, interrupted, {task key: error})."""
    from ..tasks import LocalExecutor, run_tasks

    outcome = run_tasks(tasks, executor or LocalExecutor(1), label=label)
    rows = []
    for result in outcome.results.values():
        rows.extend(result if isinstance(result, list) else [result])
    return rows, outcome.interrupted, outcome.failed


def _task_runtime():
    """Inside a task's fresh process: the Taichi runtime every study here uses."""
    from .. import runtime

    runtime.init("cpu", "f64")


# -- accuracy -------------------------------------------------------------------------------------------
def run_accuracy(quick: bool, executor=None) -> dict:
    """Work-precision of every integrator on each case: one reference task per case, then one task
    per (case, integrator) against it."""
    from ..tasks import Task

    count = 3 if quick else 6
    frames = 10
    repeats = 1 if quick else 3
    out = {"cases": {}, "interrupted": False, "failed": {}}
    sweeps = {case: {name: accuracy.step_sizes(t_end, frames, cls.sweep_dt_cap, count)
                     for name, cls in REGISTRY.items()}
              for case, (_, _, t_end) in accuracy.CASES.items()}
    refs, out["interrupted"], out["failed"] = _sweep(
        [Task(f"reference/{case}", "taichi_soft.bench.sweeps:accuracy_reference_task",
              {"case": case, "dt_min": min(min(d) for d in sw.values()), "frames": frames}) for case, sw in sweeps.items()],
        executor, "accuracy references")
    refs = {r["case"]: r for r in refs}
    if out["interrupted"]:
        return out
    tasks = [Task(f"{case}/{name}", "taichi_soft.bench.sweeps:accuracy_task",
                  {"case": case, "name": name, "dts": dts, "ref": refs[case]["ref"], "dt_ref": refs[case]["dt_ref"],
                   "frames": frames, "repeats": repeats})
             for case, sw in sweeps.items() if case in refs for name, dts in sw.items()]
    rows, out["interrupted"], failed = _sweep(tasks, executor, "accuracy")
    out["failed"].update(failed)
    for case in refs:
        case_rows = [r for r in rows if r["case"] == case]
        out["cases"][case] = {"rows": case_rows, "orders": {name: accuracy.fitted_order(case_rows, name) for name in REGISTRY}}
    return out


def accuracy_reference_task(case: str, dt_min: float, frames: int) -> dict:
    _task_runtime()
    ref, dt_ref = accuracy.reference(case, dt_min, frames)
    return {"case": case, "ref": ref, "dt_ref": dt_ref}


def accuracy_task(case: str, name: str, dts, ref, dt_ref: float, frames: int, repeats: int) -> list[dict]:
    _task_runtime()
    return accuracy.measure_integrator(case, name, dts, ref, dt_ref, frames, repeats)


def write_accuracy(result: dict, out_dir: Path) -> list[str]:
    from . import plots

    files = []
    for case, data in result["cases"].items():
        write_csv(data["rows"], out_dir / f"accuracy_{case}.csv")
        plots.work_precision(data["rows"], out_dir / f"accuracy_{case}_wall.png", f"{case}: error vs wall time")
        plots.work_precision(data["rows"], out_dir / f"accuracy_{case}_evals.png", f"{case}: error vs spring passes",
                             cost_key="force_evals")
        files += [f"accuracy_{case}.csv", f"accuracy_{case}_wall.png", f"accuracy_{case}_evals.png"]
    return files


# -- precision (work-precision at equal error, bench/precision.py) -----------------------------------------
def run_precision(quick: bool, executor=None, scales=None) -> dict:
    """References first (one task per case x stiffness), then one task per case x method x tolerance
    over every stiffness (one compile each)."""
    from ..tasks import Task
    from . import plausibility, precision

    scales = list(scales or (precision.QUICK_STIFFNESS if quick else precision.STIFFNESS))
    out = {"rows": [], "references": [], "interrupted": False, "failed": {}, "quick": quick}
    refs, out["interrupted"], out["failed"] = _sweep(
        [Task(f"precision-reference/{case}/{s:g}", "taichi_soft.bench.precision:reference_task",
              {"case": case, "scale": s, "quick": quick}) for case in precision.CASES for s in scales],
        executor, "precision references")
    out["references"] = [{k: v for k, v in r.items() if k != "members"} for r in refs]
    if out["interrupted"]:
        return out
    by_key = {f"{r['case']}/{r['stiffness_scale']:g}": r for r in refs}
    tasks = []
    for case in precision.CASES:
        case_refs = {k: v for k, v in by_key.items() if k.startswith(case + "/")}
        if len(case_refs) < len(scales):
            continue  # a reference failed: its rows are missing (listed as failed)
        for name, cls in REGISTRY.items():
            if quick and name not in precision.QUICK_METHODS:
                continue
            tols = precision.QUICK_TOLERANCES if quick else list(precision.TOLERANCES)
            for tol in (tols if cls.implicit else ["-"]):
                tasks.append(Task(f"precision/{case}/{name}/{tol}", "taichi_soft.bench.precision:method_task",
                                  {"case": case, "name": name, "tolerance": tol if cls.implicit else "default",
                                   "scales": scales, "refs": case_refs, "quick": quick}))
    # plausibility at frame steps (plausibility.py): one task per implicit solver, on the flat case's references
    flat_refs = {k: v for k, v in by_key.items() if k.startswith("flat/")}
    if len(flat_refs) == len(scales):
        for name in plausibility.SOLVERS:
            if quick and name not in precision.QUICK_METHODS:
                continue
            tasks.append(Task(f"plausibility/{name}", "taichi_soft.bench.plausibility:task",
                              {"name": name, "scales": scales, "refs": flat_refs, "quick": quick}))
    rows, out["interrupted"], failed = _sweep(tasks, executor, "precision")
    out["failed"].update(failed)
    out["rows"] = [r for r in rows if "settings" not in r]
    out["plausibility"] = [r for r in rows if "settings" in r]
    return out


def write_precision(result: dict, out_dir: Path) -> list[str]:
    from . import plots

    write_csv(result["rows"], out_dir / "precision.csv")
    write_csv([{"case": r["case"], "stiffness_scale": r["stiffness_scale"], "dt": r["dt"], **r["self_check"]}
               for r in result["references"]], out_dir / "precision_references.csv")
    plots.precision_fronts(result["rows"], out_dir / "precision_wall.png", "wall_per_sim_s",
                           "wall s per simulated s")
    plots.precision_fronts(result["rows"], out_dir / "precision_evals.png", "spring_passes_per_sim_s",
                           "spring passes per simulated s")
    write_csv(result.get("plausibility", []), out_dir / "plausibility.csv")
    return ["precision.csv", "precision_references.csv", "precision_wall.png", "precision_evals.png", "plausibility.csv"]


# -- stability ---------------------------------------------------------------------------------------------
def run_stability(quick: bool, executor=None, names=None) -> dict:
    """Largest stable dt per integrator x terrain (default stiffness), then per integrator x stiffness on
    the plane, and the wall time to simulate 1 s at each method's largest stable dt.

    One task per (integrator, terrain) and one per integrator's stiffness sweep; ``names`` limits
    the integrators (default: all registered)."""
    from ..tasks import Task

    names = list(names or REGISTRY)
    cfg = {"sets": ["body.0.n=4", "body.0.size=2.0", "body.0.center=[0, 3, 0]"] if quick else [],
           "horizon": 1.0 if quick else stability.HORIZON, "rel_tol": 0.1 if quick else 0.03, "hi": stability.DT_MAX}
    scales = stability.QUICK_STIFFNESS_SCALES if quick else stability.STIFFNESS_SCALES
    terrains = ("plane",) if quick else TERRAINS
    tasks = [Task(f"terrain/{n}/{t}", "taichi_soft.bench.sweeps:stability_terrain_task", dict(cfg, name=n, terrain=t))
             for n in names for t in terrains]
    tasks += [Task(f"stiffness/{n}", "taichi_soft.bench.sweeps:stability_stiffness_task", dict(cfg, name=n, scales=scales))
              for n in names]
    rows, interrupted, failed = _sweep(tasks, executor, "stability")
    def part(sweep):  # the tag only routes rows back; the CSVs keep their columns
        return [{k: v for k, v in r.items() if k != "sweep"} for r in rows if r["sweep"] == sweep]

    return {"terrain_rows": part("terrain"), "stiffness_rows": part("stiffness"), "interrupted": interrupted,
            "failed": failed,
            "criteria": {"horizon_s": cfg["horizon"], "energy_growth": stability.ENERGY_GROWTH,
                         "max_penetration_m": stability.MAX_PENETRATION, "dt_max_tried": cfg["hi"]},
            "quick": quick}


def stability_terrain_task(name, terrain, sets, horizon, rel_tol, hi) -> dict:
    _task_runtime()
    probe = stability.SceneProbe(terrain, name, sets, horizon=horizon)
    res = stability.largest_stable_dt(probe, DT_LO, hi, rel_tol=rel_tol)
    return {"sweep": "terrain", "integrator": name, "terrain": terrain, "stiffness_scale": 1.0, **_flat(res)}


def stability_stiffness_task(name, sets, horizon, rel_tol, hi, scales) -> list[dict]:
    _task_runtime()
    probe = stability.SceneProbe("plane", name, sets, horizon=horizon)
    rows, prev = [], None
    for scale in scales:
        probe.set_stiffness_scale(scale)
        # stable dt of an explicit method scales like 1/sqrt(k): bracket around the last answer
        lo = DT_LO if prev is None else prev / 4
        res = stability.largest_stable_dt(probe, lo, hi, rel_tol=rel_tol)
        row = {"sweep": "stiffness", "integrator": name, "terrain": "plane", "stiffness_scale": scale, **_flat(res)}
        row["wall_s_per_sim_s"] = _wall_per_second(probe, res["dt"]) if res["dt"] else None
        rows.append(row)
        prev = res["dt"] or prev
    return rows


def _flat(res: dict) -> dict:
    lo, hi = res["bracket"]
    return {"dt": res["dt"], "bounded": res["bounded"], "unstable_at": hi}


def _wall_per_second(probe, dt: float, repeats: int = 3) -> float:
    """Wall seconds [s] per simulated second of the probe's whole drop at ``dt`` (median of repeats).

    Timed over the full horizon, not the first second: that one is mostly free fall, where an
    implicit step costs almost nothing, so it would flatter the implicit methods.
    """
    sim = probe.sim

    def setup():
        sim.reset()
        sim.set_dt(dt)

    # the upper median, as before (the median for the odd repeats used)
    t = time_one(lambda: sim.advance(int(math.ceil(probe.horizon / dt))), repeats, setup=setup)
    return statistics.median_high(t.wall) / probe.horizon


def write_stability(result: dict, out_dir: Path) -> list[str]:
    from . import plots

    write_csv(result["terrain_rows"], out_dir / "stability_terrain.csv")
    write_csv(result["stiffness_rows"], out_dir / "stability_stiffness.csv")
    files = ["stability_terrain.csv", "stability_stiffness.csv"]
    if result["stiffness_rows"]:
        plots.stability_vs_stiffness(result["stiffness_rows"], out_dir / "stability_stiffness.png")
        files.append("stability_stiffness.png")
    return files
