"""``bench memory``: peak resident (and device) memory per particle, measured against the estimate.

Method: every (integrator, precision, n) runs ``main.py run --scene plane --set body.0.n=N`` for
one step as a task (``taichi_soft.tasks``: a fresh process, one at a time), which reports its own
peak resident set size (``VmHWM`` from /proc/self/status) and, on CUDA, the device memory
nvidia-smi shows for it at the end of the run.
Implicit methods run with one Newton / global iteration and a few CG iterations: their memory does
not depend on the iteration counts, their time does. Each row carries ``taichi_soft.sim.memory``'s
estimate for the same run, so the model that refuses too-large runs is checked here.

Sizes: n = 10, 20, 40, 80 and the largest n (up to the scene limit) whose estimate fits in
``FIT_FRACTION`` of the memory available when the study starts; ``quick`` (CI): three tiny runs.
"""
from __future__ import annotations

from ..sim import memory
from ..sim.scene import load_scene
from ..sim.scene_validation import MAX_N

SIZES = (10, 20, 40, 80)
# One integrator per family and precision (the explicit family's two ends, both implicit solvers).
CONFIGS = (("semi_implicit_euler", "f64"), ("semi_implicit_euler", "f32"), ("rk4", "f64"),
           ("implicit_euler", "f64"), ("fast_mass_spring", "f64"))
QUICK_JOBS = (("semi_implicit_euler", "f64", 4), ("semi_implicit_euler", "f64", 8), ("implicit_euler", "f64", 4))
FAMILY = {"implicit_euler": "implicit", "fast_mass_spring": "implicit"}
# The largest size measured leaves the rest of the machine this share of the available memory.
FIT_FRACTION = 0.5
_FEW_ITERATIONS = {"implicit_euler": ["solver.newton_iters=1", "solver.cg_iters=5"],
                   "fast_mass_spring": ["solver.iterations=1", "solver.cg_iters=5"]}

def scene_sets(n: int, integrator: str) -> list[str]:
    """The ``--set`` overrides of one measured run (the default plane scene, one body of n^3)."""
    return [f"body.0.n={n}"] + _FEW_ITERATIONS.get(integrator, [])


def measure_peaks(jobs: list[tuple[str, str, int]], arch: str = "cpu", progress=None) -> dict:
    """Peak memory of a one-step CLI run per (integrator, precision, n), each a task in a fresh
    process, one at a time: {"rows", "errors", "interrupted"}; Ctrl-C keeps the rows measured."""
    from ..tasks import LocalExecutor, Task, run_tasks

    tasks, job_of = [], {}
    for integrator, precision, n in jobs:
        argv = ["run", "--scene", "plane", "--integrator", integrator, "--precision", precision, "--arch", arch,
                "--dt", "0.001", "--duration", "0.001"]
        for s in scene_sets(n, integrator):
            argv += ["--set", s]
        key = f"memory run n={n} {integrator} {precision}"
        tasks.append(Task(key, "taichi_soft.peak_run:peak_of_run", {"argv": argv, "arch": arch}))
        job_of[key] = (integrator, precision, n)

    def finished(key, result):
        if progress:
            progress(len(finished.seen) + 1, len(tasks), key[len("memory run "):])
        finished.seen.append(key)
        return result
    finished.seen = []

    executor = LocalExecutor(1)
    try:
        outcome = run_tasks(tasks, executor, "bench memory", retries=0, bar=False, on_result=finished)
    finally:
        executor.close()
    rows, errors = [], []
    for key in job_of:
        res = outcome.results.get(key)
        if key in outcome.failed:
            errors.append(f"{key} failed: {outcome.failed[key]}")
            continue
        if res is None:  # not run: interrupted
            continue
        if res["rc"] != 0:
            errors.append(f"{key} exited {res['rc']}")
            continue
        integrator, precision, n = job_of[key]
        est = memory.estimate(load_scene("plane", scene_sets(n, integrator)).data, integrator, precision, arch)
        n_p, n_s = est["particles"], est["springs"]
        rows.append({"integrator": integrator, "family": FAMILY.get(integrator, "explicit"), "precision": precision,
                     "arch": est["arch"], "n": n, "particles": n_p, "springs": n_s, "peak_bytes": res["peak_bytes"],
                     "device_bytes": res["device_bytes"], "estimate_host_bytes": est["host"],
                     "estimate_device_bytes": est["device"], "measured_over_estimate": res["peak_bytes"] / est["host"],
                     "bytes_per_particle": res["peak_bytes"] / n_p})
    return {"rows": rows, "errors": errors, "interrupted": outcome.interrupted}


def measure_peak(n: int, integrator: str, precision: str = "f64", arch: str = "cpu") -> dict:
    """The row of one run (``measure_peaks``); RuntimeError if it failed."""
    res = measure_peaks([(integrator, precision, n)], arch)
    if not res["rows"]:
        raise RuntimeError("; ".join(res["errors"]) or "interrupted")
    return res["rows"][0]


def largest_fitting_n(integrator: str, precision: str, arch: str = "cpu", fraction: float = FIT_FRACTION) -> int | None:
    """Largest n <= MAX_N whose estimate fits in ``fraction`` of the memory available now."""
    host_avail = memory.available_bytes("cpu")
    dev_avail = memory.available_bytes(arch) if memory.resolve_arch(arch) != "cpu" else None
    if host_avail is None:
        return None
    for n in range(MAX_N, 1, -1):
        est = memory.estimate(load_scene("plane", scene_sets(n, integrator)).data, integrator, precision, arch)
        if est["host"] <= fraction * host_avail and (dev_avail is None or est["device"] <= fraction * dev_avail):
            return n
    return None


def run(quick: bool, progress=None, arch: str = "cpu") -> dict:
    """All configurations and sizes; Ctrl-C stops and keeps the rows measured so far."""
    jobs = list(QUICK_JOBS) if quick else []
    for integrator, precision in () if quick else CONFIGS:
        sizes = list(SIZES)
        big = largest_fitting_n(integrator, precision, arch)
        if big is not None and big not in sizes:
            sizes.append(big)
        jobs += [(integrator, precision, n) for n in sizes]
    return {**measure_peaks(jobs, arch, progress), "fit_fraction": FIT_FRACTION,
            "available_bytes_at_start": memory.available_bytes("cpu")}


def marginal_bytes_per_particle(rows: list[dict], n_lo: int, n_hi: int) -> dict:
    """(peak(n_hi) - peak(n_lo)) / (particles(n_hi) - particles(n_lo)) per (integrator, precision):
    the memory each added particle costs, without the fixed base of the process."""
    out = {}
    by = {(r["integrator"], r["precision"], r["n"]): r for r in rows}
    for (integ, prec, n), lo in by.items():
        hi = by.get((integ, prec, n_hi))
        if n == n_lo and hi:
            out[(integ, prec)] = (hi["peak_bytes"] - lo["peak_bytes"]) / (hi["particles"] - lo["particles"])
    return out


def markdown(result: dict) -> str:
    rows = result["rows"]
    out = ["## Memory", "",
           "Peak resident memory (VmHWM) of a one-step `run --scene plane --set body.0.n=N`, each size in a fresh "
           "process, against `taichi_soft/sim/memory.py`'s estimate (the one `run` checks before it starts). "
           "Per particle: the whole peak / particles (the process base dominates small n). "
           f"The largest size is the largest n whose estimate fits in {result['fit_fraction']:.0%} of the memory "
           "available when the study started"
           + (f" ({result['available_bytes_at_start'] / 1e9:.1f} GB)." if result.get("available_bytes_at_start") else "."),
           "",
           "| integrator | family | precision | n | particles | springs | peak [MB] | estimate [MB] | measured / estimate | bytes / particle | device [MB] |",
           "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        dev = "" if r["device_bytes"] is None else f"{r['device_bytes'] / 2**20:,.0f}"
        out.append(f"| {r['integrator']} | {r['family']} | {r['precision']} | {r['n']} | {r['particles']:,} | "
                   f"{r['springs']:,} | {r['peak_bytes'] / 2**20:,.1f} | {r['estimate_host_bytes'] / 2**20:,.1f} | "
                   f"{r['measured_over_estimate']:.2f} | {r['bytes_per_particle']:,.0f} | {dev} |")
    marg = marginal_bytes_per_particle(rows, 40, 80)
    if marg:
        out += ["", "Memory per added particle between n = 40 and n = 80 (peak difference / particle difference):", "",
                "| integrator | precision | bytes / particle |", "|---|---|---:|"]
        out += [f"| {i} | {p} | {b:,.0f} |" for (i, p), b in marg.items()]
    if result["errors"]:
        out += ["", "Failed runs:", ""] + [f"- `{e}`" for e in result["errors"]]
    out.append("")
    return "\n".join(out)
