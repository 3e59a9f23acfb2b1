"""The serial studies: speed (one task per (arch, precision), then the equal-settings
comparison: ``speed``, ``equal_settings``) and peak memory (``bench/memory.py``), with the writers
of their files. They always run one configuration at a time: their measurements need a quiet
machine.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from ..sim.integrators import REGISTRY
from . import machine
from .files import write_csv, write_text
from .speed import measure as measure_speed


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


def speed_config(arch: str, precision: str, quick: bool, profile: bool = False) -> dict:
    """A task (tasks.py), so in a process of its own: one (arch, precision) configuration with fast
    math on (the command line's default): engine rows, bandwidth bound, thread overlap; or, with
    ``profile``, only the kernel profile (the profiler's bookkeeping would slow the timed rows)."""
    from .machine_limits import bytes_per_step, measured_bandwidth, thread_overlap
    from .speed import kernel_profile

    from .. import runtime

    cfg = runtime.init(arch, precision, fast_math=True, kernel_profiler=profile,
                       pin_threads=runtime.PIN_THREADS_CLI_DEFAULT)
    if profile:
        rows = [{"n": n, "integrator": name, "tasks": kernel_profile(name, n)}
                for n in ((4,) if quick else (10, 40))
                for name in (("semi_implicit_euler",) if quick else ("semi_implicit_euler", "rk4"))]
        return {"config": cfg, "profile": rows}
    sizes = (4,) if quick else ((10, 20, 40, 80) if cfg["arch"] == "cpu" else (10, 20, 40, 100))
    # quick checks the machinery: every explicit method, and one implicit solver (each compiles for
    # seconds)
    names = [name for name in REGISTRY if not (quick and REGISTRY[name].implicit and name != "implicit_euler")]
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
    return {"config": cfg, "rows": rows, "bandwidth_bytes_per_s": bw, "bound": bound, "profile": [],
            "thread_overlap": overlap}


def run_speed(quick: bool, progress=None) -> dict:
    """``speed_config`` of each (arch, precision) as a task, one at a time (Taichi initialises once
    per process; the timings want a quiet machine), the first also profiled; then the
    equal-settings comparison, interleaved."""
    from ..runtime import available_archs
    from ..tasks import LocalExecutor, Task, run_tasks
    from .equal_settings import equal_settings, equal_settings_specs, quick_specs

    configs = speed_configs()
    tasks = []
    for k, (arch, precision) in enumerate(configs):
        kwargs = {"arch": arch, "precision": precision, "quick": quick}
        tasks.append(Task(f"speed {arch} {precision}", f"{__name__}:speed_config", kwargs))
        if k == 0:
            tasks.append(Task(f"profile {arch} {precision}", f"{__name__}:speed_config", {**kwargs, "profile": True}))
    done = []

    def finished(key, result):
        if progress and key.startswith("speed "):
            done.append(key)
            progress(len(done), len(configs), key)
        return result

    executor = LocalExecutor(1)
    try:
        outcome = run_tasks(tasks, executor, "bench speed", retries=0, bar=False, on_result=finished)
    finally:
        executor.close()
    results = []
    for t in tasks:
        if t.key in outcome.results and t.kwargs.get("profile"):
            results[-1]["profile"] = outcome.results[t.key]["profile"]
        elif t.key in outcome.results:
            results.append(outcome.results[t.key])
        elif t.key in outcome.failed:
            results.append({"config": {"arch": t.kwargs["arch"], "precision": t.kwargs["precision"]},
                            "error": outcome.failed[t.key]})
    interrupted = outcome.interrupted
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
