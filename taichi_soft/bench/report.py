"""``python main.py bench accuracy|stability|speed|memory|report``: measure, then write CSV, PNG and Markdown.

Each study returns plain rows (dicts); ``write_*`` functions turn rows into files. ``report``
runs all four and writes ``REPORT.md`` beside the CSVs and plots. ``quick`` shrinks every study
(tiny cubes, few steps) so the whole report runs in a few minutes on 2 cores; its numbers check
the machinery, not the physics at full size.

The accuracy and stability sweeps are independent runs dispatched as tasks
(``taichi_soft.tasks``: each in a fresh process, ``--workers N`` local processes or a Dask
``--scheduler``); their wall-time columns are measured under whatever else runs at the same time,
so publish timings from ``--workers 1`` on a quiet machine. The speed and memory studies always run serially,
one configuration at a time, for the same reason. A sweep interrupted with Ctrl-C stops and still
writes what it measured, marked as interrupted; a task that failed twice is listed as failed.
"""
from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import taichi as ti

from ..integrators import REGISTRY
from ..integrators.base import DIVERGENCE_SPEED2
from ..outfiles import write_atomic
from ..paths import ROOT
from ..tasks import RETRIES
from . import accuracy, machine, stability
from .speed import measure as measure_speed


# Largest dt each integrator is swept to in the accuracy study [s] (the rest are log-spaced below).
DT_CAP = {"explicit_euler": 2e-3, "semi_implicit_euler": 2e-3, "midpoint": 4e-3, "rk4": 6e-3}
DT_CAP_IMPLICIT = 2e-2
TERRAINS = ("plane", "tilted_plane", "sphere", "bowl")
WIN_MARGIN = 1.1  # a win: at least this ratio of wall times (more than the spread within one run)
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


def write_csv(rows: list[dict], path: Path):
    """Rows as CSV (columns: every key, in first-seen order), written atomically."""
    keys = list(dict.fromkeys(k for r in rows for k in r))

    def write(tmp):
        with open(tmp, "w", newline="") as f:
            if not rows:
                return
            w = csv.DictWriter(f, fieldnames=keys)
            w.writeheader()
            for r in rows:
                w.writerow({k: r.get(k) for k in keys})
    write_atomic(Path(path), write)


def write_text(path: Path, text: str):
    """A text file written atomically (a full disk or a kill never leaves half of it)."""
    write_atomic(Path(path), lambda tmp: Path(tmp).write_text(text))


# -- accuracy -------------------------------------------------------------------------------------------
def run_accuracy(quick: bool, executor=None) -> dict:
    """Work-precision of every integrator on each case: one reference task per case, then one task
    per (case, integrator) against it."""
    from ..tasks import Task

    count = 3 if quick else 6
    frames = 10
    repeats = 1 if quick else 3
    out = {"cases": {}, "interrupted": False, "failed": {}}
    sweeps = {case: {name: accuracy.step_sizes(t_end, frames, DT_CAP.get(name, DT_CAP_IMPLICIT), count) for name in REGISTRY}
              for case, (_, _, t_end) in accuracy.CASES.items()}
    refs, out["interrupted"], out["failed"] = _sweep(
        [Task(f"reference/{case}", "taichi_soft.bench.report:accuracy_reference_task",
              {"case": case, "dt_min": min(min(d) for d in sw.values()), "frames": frames}) for case, sw in sweeps.items()],
        executor, "accuracy references")
    refs = {r["case"]: r for r in refs}
    if out["interrupted"]:
        return out
    tasks = [Task(f"{case}/{name}", "taichi_soft.bench.report:accuracy_task",
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
    from . import precision

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
    rows, out["interrupted"], failed = _sweep(tasks, executor, "precision")
    out["failed"].update(failed)
    out["rows"] = rows
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
    return ["precision.csv", "precision_references.csv", "precision_wall.png", "precision_evals.png"]


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
    tasks = [Task(f"terrain/{n}/{t}", "taichi_soft.bench.report:stability_terrain_task", dict(cfg, name=n, terrain=t))
             for n in names for t in terrains]
    tasks += [Task(f"stiffness/{n}", "taichi_soft.bench.report:stability_stiffness_task", dict(cfg, name=n, scales=scales))
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
    times = []
    for _ in range(repeats):
        sim.reset()
        sim.set_dt(dt)
        ti.sync()
        t0 = time.perf_counter()
        sim.advance(int(math.ceil(probe.horizon / dt)))
        ti.sync()
        times.append((time.perf_counter() - t0) / probe.horizon)
    return sorted(times)[len(times) // 2]


def write_stability(result: dict, out_dir: Path) -> list[str]:
    from . import plots

    write_csv(result["terrain_rows"], out_dir / "stability_terrain.csv")
    write_csv(result["stiffness_rows"], out_dir / "stability_stiffness.csv")
    files = ["stability_terrain.csv", "stability_stiffness.csv"]
    if result["stiffness_rows"]:
        plots.stability_vs_stiffness(result["stiffness_rows"], out_dir / "stability_stiffness.png")
        files.append("stability_stiffness.png")
    return files


# -- speed ----------------------------------------------------------------------------------------------------
def speed_configs() -> list[tuple[str, str]]:
    """(arch, precision) pairs to measure: the CPU in f32 and f64, GPUs where present."""
    from ..runtime import available_archs

    configs = [("cpu", "f64"), ("cpu", "f32")]
    archs = available_archs()
    if "cuda" in archs:
        configs += [("cuda", "f32"), ("cuda", "f64")]
    elif "vulkan" in archs and machine.gpu_name():
        configs += [("vulkan", "f32")]  # Vulkan has no f64; on a CPU-only machine it is a software device
    return configs


def run_speed_worker(quick: bool) -> dict:
    """Inside one (arch, precision) process: engine rows, numpy/Warp comparison, bandwidth, profile."""
    from .speed import bytes_per_step, kernel_profile, measured_bandwidth, thread_overlap

    from .. import runtime

    cfg = runtime.current()
    profile = []
    if os.environ.get("TAICHI_SOFT_PROFILE") == "1":
        # A separate process only for the profile: the profiler's bookkeeping would slow the
        # timed rows, so those come from the unprofiled worker.
        for n in (4,) if quick else (10, 40):
            for name in ("semi_implicit_euler",) if quick else ("semi_implicit_euler", "rk4"):
                profile.append({"n": n, "integrator": name, "tasks": kernel_profile(name, n)})
        return {"config": cfg, "profile": profile}
    sizes = (4,) if quick else ((10, 20, 40, 80) if cfg["arch"] == "cpu" else (10, 20, 40, 100))
    names = list(REGISTRY)
    rows = []
    for n in sizes:
        for name in names:
            if REGISTRY[name].implicit and n > 40:
                continue  # implicit methods at 80^3 take minutes per repeat here; measured up to 40^3
            rows.append(measure_speed(name, n, repeats=2 if quick else 5))
    bw = measured_bandwidth(32 if quick else 256)
    overlap = thread_overlap((1.0,) if quick else (0.3, 1.0, 3.0, 10.0)) if cfg["arch"] == "cpu" else []
    real_bytes = 8 if cfg["precision"] == "f64" else 4
    bound = []
    for r in rows:
        if r["integrator"] != "semi_implicit_euler":
            continue
        b = bytes_per_step(r["particles"], r["springs"], real_bytes, r["forces"], r.get("row_width", 0))
        bound.append({"n": r["n"], "bytes_per_step": b, "bound_steps_per_s": bw / b,
                      "measured_steps_per_s": r["steps_per_s"], "fraction_of_bound": r["steps_per_s"] * b / bw})
    return {"config": cfg, "rows": rows, "bandwidth_bytes_per_s": bw, "bound": bound, "profile": profile,
            "thread_overlap": overlap}


def run_speed(quick: bool, progress=None) -> dict:
    """One subprocess per (arch, precision) configuration (Taichi initialises once per process),
    fast math on (the command line's default); then the equal-settings comparison, interleaved."""
    from ..runtime import available_archs
    from .speed import equal_settings, equal_settings_specs, quick_specs

    results, interrupted = [], False
    configs = speed_configs()
    for k, (arch, precision) in enumerate(configs):
        for profile in (False, True):
            if profile and (arch, precision) != configs[0]:
                continue
            cmd = [sys.executable, str(ROOT / "main.py"), "bench", "speed-worker", "--arch", arch, "--precision",
                   precision, "--fast-math"] + (["--quick"] if quick else [])
            env = dict(os.environ, TAICHI_SOFT_PROFILE="1" if profile else "0")
            try:
                proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT)
            except KeyboardInterrupt:
                interrupted = True
                break
            if proc.returncode != 0:
                results.append({"config": {"arch": arch, "precision": precision}, "error": proc.stderr.strip()[-500:]})
                continue
            data = json.loads(proc.stdout.strip().splitlines()[-1])
            if profile:
                results[-1]["profile"] = data["profile"]
            else:
                results.append(data)
        if interrupted:
            break
        if progress:
            progress(k + 1, len(configs), f"speed {arch} {precision}")
    equal = []
    if not interrupted:
        gpus = tuple(a for a in available_archs() if a == "cuda")
        specs = quick_specs() if quick else equal_settings_specs(archs=("cpu",) + gpus)
        try:
            equal = equal_settings(specs, rounds=2 if quick else 7, progress=progress)
        except KeyboardInterrupt:
            interrupted = True
    return {"configs": results, "equal_settings": equal, "load_average": os.getloadavg(), "interrupted": interrupted}


def write_speed(result: dict, out_dir: Path) -> list[str]:
    from . import plots

    files = []
    all_rows = []
    for res in result["configs"]:
        if "rows" not in res:
            continue
        tag = f"{res['config']['arch']}_{res['config']['precision']}"
        for r in res["rows"]:
            all_rows.append({"arch": res["config"]["arch"], "precision": res["config"]["precision"], **r})
        plots.speed_bars(res["rows"], out_dir / f"speed_{tag}.png", f"{tag}: ns per particle-step (lower is better)")
        files.append(f"speed_{tag}.png")
    write_csv(all_rows, out_dir / "speed.csv")
    write_csv(result.get("equal_settings", []), out_dir / "speed_equal.csv")
    write_text(out_dir / "speed.json", json.dumps(result, indent=1))
    return files + ["speed.csv", "speed_equal.csv", "speed.json"]


# -- memory ------------------------------------------------------------------------------------------------
def run_memory(quick: bool, progress=None) -> dict:
    """Peak memory per size, one subprocess each (bench/memory.py)."""
    from . import memory

    return memory.run(quick, progress)


def write_memory(result: dict, out_dir: Path) -> list[str]:
    write_csv(result["rows"], out_dir / "memory.csv")
    return ["memory.csv"]


# -- Markdown ------------------------------------------------------------------------------------------------
def _sci(x: float) -> str:
    """``x`` in the docs' short scientific form: 1e6, 2.5e-4."""
    mantissa, exponent = f"{x:e}".split("e")
    return f"{float(mantissa):g}e{int(exponent)}"


def _fmt(x, spec=".3g"):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return format(x, spec)


def accuracy_markdown(result: dict) -> str:
    out = ["## Work-precision", "",
           "RMS particle position error [m] against RK4 (f64, fast math off) at a step 10 times smaller than the "
           "smallest swept. `smooth`: free-floating 5^3 cube started stretched (no contact); `drop`: 5^3 cube dropped "
           "onto the plane (contact: not smooth, orders drop). Cost: wall time (minimum of repeats after a warm-up) "
           "and spring passes (force evaluations; for the implicit solvers every objective, gradient and "
           "Hessian-product evaluation, `Integrator.spring_passes_per_step`).", ""]
    for case, data in result["cases"].items():
        out += [f"### {case}", "", f"![{case} error vs wall time](accuracy_{case}_wall.png)",
                f"![{case} error vs spring passes](accuracy_{case}_evals.png)", "",
                "| integrator | fitted order (final error vs dt) | smallest error [m] | its wall time [s] |", "|---|---:|---:|---:|"]
        for name, order in data["orders"].items():
            ok = [r for r in data["rows"] if r["integrator"] == name and not r["diverged"]]
            best = min(ok, key=lambda r: r["error_final"]) if ok else None
            out.append(f"| {name} | {_fmt(order, '.2f')} | {_fmt(best and best['error_final'])} | "
                       f"{_fmt(best and best['wall_s'])} |")
        out.append("")
    return "\n".join(out)


def stability_markdown(result: dict) -> str:
    c = result["criteria"]
    out = ["## Stability", "",
           f"Largest stable dt by bisection on log dt (relative resolution a few %). Unstable means: the divergence "
           f"check fires (non-finite velocity or |v|^2 > {_sci(DIVERGENCE_SPEED2)}), total energy grows "
           f"by more than {c['energy_growth']:.0%} of its scale, or a particle is deeper than {c['max_penetration_m']} m in the "
           f"terrain, within {c['horizon_s']} s. Steps up to {c['dt_max_tried']} s were tried ('>=' marks a method "
           "stable at the largest). Default cube" + (" (quick: 4^3, dropped from 3 m)" if result["quick"] else "") + ".", ""]
    terrains = list(dict.fromkeys(r["terrain"] for r in result["terrain_rows"]))
    names = list(dict.fromkeys(r["integrator"] for r in result["terrain_rows"]))
    if names:
        out += ["| integrator | " + " | ".join(terrains) + " | seed (plane) |", "|---|" + "---:|" * (len(terrains) + 1)]
        for name in names:
            cells = []
            for t in terrains:
                r = next(r for r in result["terrain_rows"] if r["integrator"] == name and r["terrain"] == t)
                cells.append(("" if r["bounded"] else ">= ") + _fmt(r["dt"], ".4f") if r["dt"] else f"< {r['unstable_at']:g}")
            out.append(f"| {name} | " + " | ".join(cells) + f" | {_fmt(stability.SEED_TABLE.get(name), '.4f')} |")
        out.append("")
    if result["stiffness_rows"]:
        scales = list(dict.fromkeys(r["stiffness_scale"] for r in result["stiffness_rows"]))
        out += ["### Against stiffness (plane)", "", "![stable dt against stiffness](stability_stiffness.png)", "",
                "Largest stable dt [s] / wall time per simulated second at that dt [s] (timed over the whole drop):", "",
                "| integrator | " + " | ".join(f"k x{s:g}" for s in scales) + " |", "|---|" + "---:|" * len(scales)]
        for name in dict.fromkeys(r["integrator"] for r in result["stiffness_rows"]):
            cells = []
            for s in scales:
                r = next((r for r in result["stiffness_rows"] if r["integrator"] == name and r["stiffness_scale"] == s), None)
                if r is None or not r["dt"]:
                    cells.append("-")
                else:
                    cells.append(("" if r["bounded"] else ">= ") + f"{r['dt']:.2e} / {_fmt(r['wall_s_per_sim_s'], '.3g')}")
            out.append(f"| {name} | " + " | ".join(cells) + " |")
        out += ["", *implicit_wins_markdown(result["stiffness_rows"], scales)]
        out.append("")
    return "\n".join(out)


def implicit_wins_markdown(rows: list[dict], scales: list) -> list[str]:
    """Per stiffness, the fastest explicit and implicit method at its own largest stable dt and
    their ratio of wall time per simulated second; the smallest stiffness from which implicit wins
    (by ``WIN_MARGIN`` or more, at it and every larger stiffness)."""
    def best(scale, implicit):
        found = [r for r in rows if r["stiffness_scale"] == scale and r["dt"] and r.get("wall_s_per_sim_s")
                 and REGISTRY[r["integrator"]].implicit == implicit]
        return min(found, key=lambda r: r["wall_s_per_sim_s"], default=None)

    out = ["Fastest method of each family at its own largest stable dt (wall s per simulated s); ratio > 1: "
           "implicit faster:", "", "| stiffness | best explicit | best implicit | explicit / implicit |", "|---|---|---|---:|"]
    wins_from = None
    for scale in scales:
        e, i = best(scale, False), best(scale, True)
        if e is None or i is None:
            continue
        ratio = e["wall_s_per_sim_s"] / i["wall_s_per_sim_s"]
        if ratio >= WIN_MARGIN and wins_from is None:
            wins_from = scale
        elif ratio < WIN_MARGIN:
            wins_from = None  # it must keep winning at every larger stiffness
        out.append(f"| x{scale:g} | {e['integrator']} {e['wall_s_per_sim_s']:.3g} | {i['integrator']} "
                   f"{i['wall_s_per_sim_s']:.3g} | {ratio:.2f} |")
    out += ["", f"Implicit wins (by {WIN_MARGIN - 1:.0%} or more) from stiffness x{wins_from:g} on." if wins_from is not None
            else "Implicit does not win at the largest stiffness measured."]
    return out


def speed_markdown(result: dict) -> str:
    out = ["## Kernel speed", "",
           "Median steps/s over repeats after a warm-up (`ti.sync()` before each clock read), the default cube "
           "(edge 4 m) of n^3 particles dropped on the plane, dt = 1 ms, fast math on (the command line's "
           "default). `launch`: serial = many steps per kernel launch on one thread, parallel = one launch per "
           "step over all cores.", ""]
    if result.get("equal_settings"):
        out += equal_settings_markdown(result["equal_settings"], result.get("load_average", ()))
    for res in result["configs"]:
        cfg = res["config"]
        out.append(f"### {cfg['arch']}, {cfg['precision']}")
        out.append("")
        if cfg.get("optimize") is False:  # (runtime.OPTIMIZE_ENV: kernels the users do not get by default)
            out += ["Kernels compiled **without** Taichi's IR optimisation passes (`TAICHI_SOFT_OPTIMIZE=0`).", ""]
        if "error" in res:
            out += [f"Failed: `{res['error']}`", ""]
            continue
        from .speed import table

        out += [table(res["rows"]), "", f"![speed {cfg['arch']} {cfg['precision']}](speed_{cfg['arch']}_{cfg['precision']}.png)", ""]
        out += [f"Measured copy bandwidth: {res['bandwidth_bytes_per_s'] / 1e9:.1f} GB/s. Memory-bandwidth bound of a "
                "semi-implicit step (compulsory traffic / bandwidth). A fraction above 1 means the working set "
                "fits in cache, where main-memory bandwidth does not bound the step:", "",
                "| n | bytes / step | bound steps/s | measured steps/s | fraction of bound |", "|---:|---:|---:|---:|---:|"]
        for b in res["bound"]:
            out.append(f"| {b['n']} | {b['bytes_per_step']:,} | {b['bound_steps_per_s']:,.0f} | "
                       f"{b['measured_steps_per_s']:,.0f} | {b['fraction_of_bound']:.2f} |")
        out.append("")
        if res.get("thread_overlap"):
            out += ["Thread overlap on this machine: a parallel loop of two equal tasks, each alone taking the time "
                    "in the first column; overlap 1 = both threads ran them at once, 0 = one after the other (the "
                    "second thread joined too late). The step kernels' 2-thread scaling cannot beat this for loops "
                    "of their length.", "", "| one task [ms] | two tasks [ms] | overlap |", "|---:|---:|---:|"]
            for o in res["thread_overlap"]:
                out.append(f"| {o['task_ms']:.2f} | {o['two_tasks_ms']:.2f} | {o['overlap']:.2f} |")
            out.append("")
        for p in res.get("profile", []):
            out += [f"Kernel profile, {p['integrator']}, n = {p['n']} (parallel launch; task k = k-th loop of the step):", "",
                    "| task | ms / step | share |", "|---|---:|---:|"]
            for t in sorted(p["tasks"], key=lambda t: -t["share"]):
                out.append(f"| {t['task']} | {t['ms_per_step']:.4f} | {t['share']:.0%} |")
            out.append("")
    return "\n".join(out)


GOALS = (  # issues 12 and 25: (label, numerator row, denominator row, goal ratio)
    ("f32 + fast math / Warp CPU f32, n = 10", dict(group="n10", kind="engine", precision="f32", fast_math=True),
     dict(group="n10", kind="warp", precision="f32", arch="cpu"), 3.0),
    ("f32 through run (plane) / Warp CPU f32, n = 10", dict(group="n10", kind="run", precision="f32"),
     dict(group="n10", kind="warp", precision="f32", arch="cpu"), 2.8),
    ("f32 through run (plane) / engine kernel, n = 10", dict(group="n10", kind="run", precision="f32"),
     dict(group="n10", kind="engine", precision="f32", fast_math=True), 0.9),
    ("f32 + fast math / Warp CPU f32, n = 40", dict(group="n40", kind="engine", precision="f32", fast_math=True),
     dict(group="n40", kind="warp", precision="f32", arch="cpu"), 3.0),
    ("f32 + fast math / yardstick f32, n = 40", dict(group="n40", kind="engine", precision="f32", fast_math=True),
     dict(group="n40", kind="yardstick", precision="f32"), 0.9),
    ("f64 + fast math / Warp CPU f64, n = 40", dict(group="n40", kind="engine", precision="f64", fast_math=True),
     dict(group="n40", kind="warp", precision="f64", arch="cpu"), 2.5),
    ("f64 + fast math / yardstick f64, n = 40", dict(group="n40", kind="engine", precision="f64", fast_math=True),
     dict(group="n40", kind="yardstick", precision="f64"), None),
    ("2 threads / 1 thread, f32, n = 40", dict(group="threads_n40", kind="engine", precision="f32", threads=2),
     dict(group="threads_n40", kind="engine", precision="f32", threads=1), 1.85),
    ("engine / yardstick, f32, n = 40, 1 thread", dict(group="threads_n40", kind="engine", precision="f32", threads=1),
     dict(group="threads_n40", kind="yardstick", precision="f32", threads=1), 0.9),
    ("engine / yardstick, f32, n = 40, 2 threads", dict(group="threads_n40", kind="engine", precision="f32", threads=2),
     dict(group="threads_n40", kind="yardstick", precision="f32", threads=2), 0.9),
    ("2 threads / 1 thread, f64, n = 40", dict(group="threads_n40", kind="engine", precision="f64", threads=2),
     dict(group="threads_n40", kind="engine", precision="f64", threads=1), None),
    ("2 threads / 1 thread, f32, n = 80", dict(group="threads_n80", kind="engine", precision="f32", threads=2),
     dict(group="threads_n80", kind="engine", precision="f32", threads=1), None),
    ("2 threads / 1 thread, f64, n = 80", dict(group="threads_n80", kind="engine", precision="f64", threads=2),
     dict(group="threads_n80", kind="engine", precision="f64", threads=1), None),
)


def equal_settings_markdown(rows: list[dict], load) -> list[str]:
    from .speed import find_row

    out = ["### Equal settings, interleaved", "",
           "Semi-implicit Euler on the default cube without terrain, started stretched (springs and dampers all "
           "working), dt = 1 ms, the same steps from the same state in every column. Each configuration runs in its "
           "own process (precision, fast math and thread count are fixed when Taichi or Warp starts); after "
           "compiling and a warm-up the processes time one repeat (about 0.25 s of steps) each in turn, round after "
           "round, so the ratios below come from one interleaved run. Median steps/s; spread = (max - min) / median "
           "of the repeats. Warp: its CPU backend (one thread) with its `fast_math` module option. `ns / spring`: "
           "wall time per step over the number of springs; `ns / eval`: over the spring evaluations (a gather "
           "evaluates each spring twice, once from each end). `yardstick`: the plain Taichi gather kernel of "
           "the yardstick taichi_ref.py (outside this repository; re-implemented here) (CSR rows, per-entry k and kd, no terrain, no checks) on the same cube. "
           "`via run`: the engine through `Simulation.run` (30 fps frame schedule, progress callback) with the "
           "plane terrain, as `run` without a video does. `steps / CPU s`: steps per second of the worker's CPU "
           "time (all its threads): on a loaded machine, where other processes take the cores, it is the steadier "
           "measure of the code itself (for 2 threads it counts both). `max abs diff`: final positions after 20 steps against "
           "the group's first row (f64, fast math off; at 1 thread for the scaling rows) [m]. "
           "`thread overlap` (2-thread rows): after each of their repeats, two equal 2-ms tasks of one parallel "
           "loop were timed: 1 = the machine ran both threads at once, 0 = one after the other (median). "
           f"Load average (1, 5, 15 min) when the study ended: {', '.join(f'{x:.2f}' for x in load)}.", "",
           "| group | code | arch | precision | fast math | threads | launch, forces | steps/s | ns / spring | ns / eval | spread | steps / CPU s | max abs diff [m] |",
           "|---|---|---|---|---|---:|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        code = {"engine": "taichi-soft", "run": "taichi-soft via run", "yardstick": "yardstick", "numpy": "numpy",
                "warp": "Warp"}[r["kind"]]
        if "error" in r:
            reason = r["error"].strip().splitlines()[-1][:200] if r["error"].strip() else "failed"
            out.append(f"| {r['group']} | {code} | {r['arch']} | {r['precision']} | | | | not run: {reason} | | | | | |")
            continue
        fm = "-" if r.get("fast_math") is None else ("on" if r["fast_math"] else "off")
        threads = r["threads"] if r.get("threads") else (
            "all" if r["kind"] in ("engine", "run", "yardstick") else "1" if r["kind"] == "warp" else "-")
        out.append(f"| {r['group']} | {code} | {r['arch']} | {r['precision']} | {fm} | {threads} | {r['mode'] or '-'} | "
                   f"{r['steps_per_s']:,.0f} | {r['ns_per_spring']:.2f} | {_fmt(r.get('ns_per_eval'), '.2f')} | "
                   f"{r['spread']:.0%} | "
                   f"{r['steps_per_cpu_s']:,.0f} | {r['max_abs_diff']:.1e} |")
    ratios = []
    for label, num, den, goal in GOALS:
        a, b = find_row(rows, **num), find_row(rows, **den)
        if a is None or b is None:
            continue
        ratio = a["steps_per_s"] / b["steps_per_s"]
        per_cpu = a["steps_per_cpu_s"] / b["steps_per_cpu_s"] if a.get("threads") is None else None
        if "thread_overlap" in a:  # what the machine allowed while the 2-thread repeats ran
            label += f" (thread overlap {a['thread_overlap']:.2f})"
        ratios.append(f"| {label} | {ratio:.2f} | {_fmt(per_cpu, '.2f')} | {'-' if goal is None else f'>= {goal:g}'} |")
    for prec in ("f64", "f32"):
        for n in (10, 40):
            on = find_row(rows, group=f"n{n}", kind="engine", precision=prec, fast_math=True, arch="cpu")
            off = find_row(rows, group=f"n{n}", kind="engine", precision=prec, fast_math=False, arch="cpu")
            npy = find_row(rows, group=f"n{n}", kind="numpy", precision=prec)
            for label, a, b in (("fast math on / off", on, off), ("engine (fast math) / numpy", on, npy)):
                if a and b:
                    ratios.append(f"| {label}, {prec}, n = {n} | {a['steps_per_s'] / b['steps_per_s']:.2f} | "
                                  f"{a['steps_per_cpu_s'] / b['steps_per_cpu_s']:.2f} | - |")
    if ratios:
        out += ["", "Ratios of medians (wall time; per CPU second where both sides are the default thread count):", "",
                "| ratio (same run) | wall | per CPU s | goal |", "|---|---:|---:|---:|", *ratios]
    out.append("")
    return out


def write_report(out_dir: Path, command: str, acc: dict | None, stab: dict | None, speed: dict | None,
                 seconds: float, mem: dict | None = None, name: str = "REPORT.md", prec: dict | None = None) -> Path:
    """The Markdown report of the studies given, as ``out_dir / name`` (``bench speed`` writes
    SPEED.md: a single study never replaces the full REPORT.md)."""
    info = machine.describe()
    parts = ["# taichi-soft benchmark report", "",
             f"Command: `{command}` ({seconds / 60:.1f} min)", "", "Machine:", "", machine.markdown(info)]
    if any(r and r.get("interrupted") for r in (acc, stab, speed, mem, prec)):
        parts += ["**Interrupted (Ctrl-C): the tables hold what was measured before the stop.**", ""]
    failed = {k: v for r in (acc, stab, prec) if r for k, v in r.get("failed", {}).items()}
    if failed:
        parts += [f"**Failed tasks (each submitted {RETRIES + 1} times): their rows are missing from the tables.**", ""]
        parts += [f"* `{k}`: {v[:300]}" for k, v in failed.items()] + [""]
    if acc:
        parts.append(accuracy_markdown(acc))
    if prec:
        from .verdict import markdown as precision_markdown

        parts.append(precision_markdown(prec))
    if stab:
        parts.append(stability_markdown(stab))
    if speed:
        parts.append(speed_markdown(speed))
    if mem:
        from .memory import markdown as memory_markdown

        parts.append(memory_markdown(mem))
    path = out_dir / name
    write_text(path, "\n".join(parts) + "\n")
    return path
