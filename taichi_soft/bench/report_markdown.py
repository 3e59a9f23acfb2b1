"""The Markdown sections of the benchmark report: one function per study turning its result
(plain rows, as the studies return them) into tables and text.
"""
from __future__ import annotations

import math

from ..sim.integrators import REGISTRY
from ..sim.integrators.base import DIVERGENCE_SPEED2
from . import stability

WIN_MARGIN = 1.1  # a win: at least this ratio of wall times (more than the spread within one run)


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
                    "second thread joined too late), with the pool's workers pinned one to a core (cpu_threads.py). "
                    "The step kernels' 2-thread scaling cannot beat this for loops of their length.", "",
                    "| one task [ms] | two tasks [ms] | overlap |", "|---:|---:|---:|"]
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


GOALS = (  # the speed goals: (label, numerator row, denominator row, goal ratio)
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
    from .equal_settings import find_row

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
