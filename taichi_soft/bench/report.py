"""``python main.py bench accuracy|stability|speed|report``: measure, then write CSV, PNG and Markdown.

Each study returns plain rows (dicts); ``write_*`` functions turn rows into files. ``report``
runs all three and writes ``REPORT.md`` beside the CSVs and plots. ``quick`` shrinks every study
(tiny cubes, few steps) so the whole report runs in a few minutes on 2 cores; its numbers check
the machinery, not the physics at full size.

A sweep interrupted with Ctrl-C stops and still writes what it measured, marked as interrupted.
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
from . import accuracy, machine, stability
from .speed import measure as measure_speed

ROOT = Path(__file__).resolve().parents[2]

# Largest dt each integrator is swept to in the accuracy study [s] (the rest are log-spaced below).
DT_CAP = {"explicit_euler": 2e-3, "semi_implicit_euler": 2e-3, "midpoint": 4e-3, "rk4": 6e-3}
DT_CAP_IMPLICIT = 2e-2
TERRAINS = ("plane", "tilted_plane", "sphere", "bowl")
DT_LO = 2.5e-4  # [s] lower end of each bisection: every method here is stable at it on the default cube


class Interrupted(Exception):
    """Raised inside a sweep after Ctrl-C; the rows gathered so far travel with it."""


def _sweep(jobs, run_one, progress, label):
    """Run ``run_one(job)`` for each job; Ctrl-C stops the sweep and keeps what was done."""
    rows, interrupted = [], False
    for k, job in enumerate(jobs):
        try:
            result = run_one(job)
        except KeyboardInterrupt:
            interrupted = True
            break
        rows.extend(result if isinstance(result, list) else [result])
        if progress:
            progress(k + 1, len(jobs), f"{label}: {job}")
    return rows, interrupted


def write_csv(rows: list[dict], path: Path):
    if not rows:
        path.write_text("")
        return
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k) for k in keys})


# -- accuracy -------------------------------------------------------------------------------------------
def run_accuracy(quick: bool, progress=None) -> dict:
    count = 3 if quick else 6
    frames = 10
    out = {"cases": {}, "interrupted": False}
    for case, (_, _, t_end) in accuracy.CASES.items():
        sweeps = {name: accuracy.step_sizes(t_end, frames, DT_CAP.get(name, DT_CAP_IMPLICIT), count) for name in REGISTRY}
        rows, interrupted = accuracy.run_case(case, sweeps, frames=frames, repeats=1 if quick else 3, progress=progress)
        out["cases"][case] = {"rows": rows, "orders": {name: accuracy.fitted_order(rows, name) for name in REGISTRY}}
        if interrupted:
            out["interrupted"] = True
            break
    return out


def write_accuracy(result: dict, out_dir: Path) -> list[str]:
    from . import plots

    files = []
    for case, data in result["cases"].items():
        write_csv(data["rows"], out_dir / f"accuracy_{case}.csv")
        plots.work_precision(data["rows"], out_dir / f"accuracy_{case}_wall.png", f"{case}: error vs wall time")
        plots.work_precision(data["rows"], out_dir / f"accuracy_{case}_evals.png", f"{case}: error vs force evaluations",
                             cost_key="force_evals")
        files += [f"accuracy_{case}.csv", f"accuracy_{case}_wall.png", f"accuracy_{case}_evals.png"]
    return files


# -- stability ---------------------------------------------------------------------------------------------
def run_stability(quick: bool, progress=None) -> dict:
    """Largest stable dt per integrator x terrain (default stiffness), then per integrator x stiffness on
    the plane, and the wall time to simulate 1 s at each method's largest stable dt."""
    names = list(REGISTRY)
    sets = ["body.0.n=4", "body.0.size=2.0", "body.0.center=[0, 3, 0]"] if quick else []
    horizon = 1.0 if quick else 2.0
    scales = stability.QUICK_STIFFNESS_SCALES if quick else stability.STIFFNESS_SCALES
    terrains = ("plane",) if quick else TERRAINS
    rel_tol = 0.1 if quick else 0.03
    hi = stability.DT_MAX

    def terrain_job(job):
        name, terrain = job
        probe = stability.SceneProbe(terrain, name, sets, horizon=horizon)
        res = stability.largest_stable_dt(probe, DT_LO, hi, rel_tol=rel_tol)
        return {"integrator": name, "terrain": terrain, "stiffness_scale": 1.0, **_flat(res)}

    terrain_rows, interrupted = _sweep([(n, t) for n in names for t in terrains], terrain_job, progress,
                                       "stability terrain")
    sweep_rows = []
    if not interrupted:
        def stiffness_job(name):
            probe = stability.SceneProbe("plane", name, sets, horizon=horizon)
            rows, prev = [], None
            for scale in scales:
                probe.set_stiffness_scale(scale)
                # stable dt of an explicit method scales like 1/sqrt(k): bracket around the last answer
                lo = DT_LO if prev is None else prev / 4
                res = stability.largest_stable_dt(probe, lo, hi, rel_tol=rel_tol)
                row = {"integrator": name, "terrain": "plane", "stiffness_scale": scale, **_flat(res)}
                row["wall_s_per_sim_s"] = _wall_per_second(probe, res["dt"]) if res["dt"] else None
                rows.append(row)
                prev = res["dt"] or prev
            return rows

        sweep_rows, interrupted = _sweep(names, stiffness_job, progress, "stability stiffness")
    return {"terrain_rows": terrain_rows, "stiffness_rows": sweep_rows, "interrupted": interrupted,
            "criteria": {"horizon_s": horizon, "energy_growth": 0.05, "max_penetration_m": 0.1, "dt_max_tried": hi},
            "quick": quick}


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
    from .speed import bytes_per_step, compare_references, kernel_profile, measured_bandwidth

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
    refs = [compare_references(n, cfg["precision"], 20 if quick else (200 if n <= 20 else 20), repeats=2 if quick else 5)
            for n in (sizes if quick else (10, 40))]
    bw = measured_bandwidth(32 if quick else 256)
    real_bytes = 8 if cfg["precision"] == "f64" else 4
    bound = []
    for r in rows:
        if r["integrator"] != "semi_implicit_euler":
            continue
        strategy = "per_spring" if r["mode"] == "serial" else "gather"
        b = bytes_per_step(r["particles"], r["springs"], real_bytes, strategy)
        bound.append({"n": r["n"], "bytes_per_step": b, "bound_steps_per_s": bw / b,
                      "measured_steps_per_s": r["steps_per_s"], "fraction_of_bound": r["steps_per_s"] * b / bw})
    return {"config": cfg, "rows": rows, "references": refs, "bandwidth_bytes_per_s": bw, "bound": bound, "profile": profile}


def run_speed(quick: bool, progress=None) -> dict:
    """One subprocess per (arch, precision) configuration (Taichi initialises once per process)."""
    results, interrupted = [], False
    configs = speed_configs()
    for k, (arch, precision) in enumerate(configs):
        for profile in (False, True):
            if profile and (arch, precision) != configs[0]:
                continue
            cmd = [sys.executable, str(ROOT / "main.py"), "bench", "speed-worker", "--arch", arch, "--precision",
                   precision] + (["--quick"] if quick else [])
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
    return {"configs": results, "interrupted": interrupted}


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
    (out_dir / "speed.json").write_text(json.dumps(result, indent=1))
    return files + ["speed.csv", "speed.json"]


# -- Markdown ------------------------------------------------------------------------------------------------
def _fmt(x, spec=".3g"):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return format(x, spec)


def accuracy_markdown(result: dict) -> str:
    out = ["## Work-precision", "",
           "RMS particle position error [m] against RK4 (f64, fast math off) at a step 10 times smaller than the "
           "smallest swept. `smooth`: free-floating 5^3 cube started stretched (no contact); `drop`: 5^3 cube dropped "
           "onto the plane (contact: not smooth, orders drop). Cost: wall time (minimum of repeats after a warm-up) "
           "and force evaluations.", ""]
    for case, data in result["cases"].items():
        out += [f"### {case}", "", f"![{case} error vs wall time](accuracy_{case}_wall.png)",
                f"![{case} error vs force evaluations](accuracy_{case}_evals.png)", "",
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
           f"check fires (non-finite velocity or |v|^2 > 1e6), total energy grows by more than "
           f"{c['energy_growth']:.0%} of its scale, or a particle is deeper than {c['max_penetration_m']} m in the "
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
        out.append("")
    return "\n".join(out)


def speed_markdown(result: dict) -> str:
    out = ["## Kernel speed", "",
           "Median steps/s over repeats after a warm-up (`ti.sync()` before each clock read), the default cube "
           "(edge 4 m) of n^3 particles dropped on the plane, dt = 1 ms. `launch`: serial = many steps per "
           "kernel launch on one thread, parallel = one launch per step over all cores.", ""]
    for res in result["configs"]:
        cfg = res["config"]
        out.append(f"### {cfg['arch']}, {cfg['precision']}")
        out.append("")
        if "error" in res:
            out += [f"Failed: `{res['error']}`", ""]
            continue
        from .speed import table

        out += [table(res["rows"]), "", f"![speed {cfg['arch']} {cfg['precision']}](speed_{cfg['arch']}_{cfg['precision']}.png)", ""]
        out += ["Semi-implicit Euler on the same cube without terrain, same steps from the same state "
                "(final states agree to the max abs difference shown):", "",
                "| n | engine steps/s | numpy steps/s | Warp CPU steps/s | engine / Warp | engine / numpy | max abs diff (numpy, Warp) [m] |",
                "|---:|---:|---:|---:|---:|---:|---|"]
        for r in res["references"]:
            out.append(f"| {r['n']} | {r['engine_steps_per_s']:,.0f} | {r['numpy_steps_per_s']:,.0f} | "
                       f"{_fmt(r.get('warp_cpu_steps_per_s'), ',.0f')} | {_fmt(r.get('ratio_engine_over_warp_cpu'), '.2f')} | "
                       f"{r['ratio_engine_over_numpy']:.1f} | {r['max_abs_diff_numpy']:.1e}, {_fmt(r.get('max_abs_diff_warp'), '.1e')} |")
        out += ["", f"Measured copy bandwidth: {res['bandwidth_bytes_per_s'] / 1e9:.1f} GB/s. Memory-bandwidth bound of a "
                "semi-implicit step (compulsory traffic / bandwidth). A fraction above 1 means the working set "
                "fits in cache, where main-memory bandwidth does not bound the step:", "",
                "| n | bytes / step | bound steps/s | measured steps/s | fraction of bound |", "|---:|---:|---:|---:|---:|"]
        for b in res["bound"]:
            out.append(f"| {b['n']} | {b['bytes_per_step']:,} | {b['bound_steps_per_s']:,.0f} | "
                       f"{b['measured_steps_per_s']:,.0f} | {b['fraction_of_bound']:.2f} |")
        out.append("")
        for p in res.get("profile", []):
            out += [f"Kernel profile, {p['integrator']}, n = {p['n']} (parallel launch; task k = k-th loop of the step):", "",
                    "| task | ms / step | share |", "|---|---:|---:|"]
            for t in sorted(p["tasks"], key=lambda t: -t["share"]):
                out.append(f"| {t['task']} | {t['ms_per_step']:.4f} | {t['share']:.0%} |")
            out.append("")
    return "\n".join(out)


def write_report(out_dir: Path, command: str, acc: dict | None, stab: dict | None, speed: dict | None,
                 seconds: float) -> Path:
    info = machine.describe()
    parts = ["# taichi-soft benchmark report", "",
             f"Command: `{command}` ({seconds / 60:.1f} min)", "", "Machine:", "", machine.markdown(info)]
    if any(r and r.get("interrupted") for r in (acc, stab, speed)):
        parts += ["**Interrupted (Ctrl-C): the tables hold what was measured before the stop.**", ""]
    if acc:
        parts.append(accuracy_markdown(acc))
    if stab:
        parts.append(stability_markdown(stab))
    if speed:
        parts.append(speed_markdown(speed))
    path = out_dir / "REPORT.md"
    path.write_text("\n".join(parts) + "\n")
    return path
