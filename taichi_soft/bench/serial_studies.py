"""The serial studies: speed (one subprocess per (arch, precision), then the equal-settings
comparison: ``speed``, ``equal_settings``) and peak memory (``bench/memory.py``), with the writers
of their files. They always run one configuration at a time: their measurements need a quiet
machine.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from ..integrators import REGISTRY
from ..paths import ROOT
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


def run_speed_worker(quick: bool) -> dict:
    """Inside one (arch, precision) process: engine rows, numpy/Warp comparison, bandwidth, profile."""
    from .machine_limits import bytes_per_step, measured_bandwidth, thread_overlap
    from .speed import kernel_profile

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
    from .equal_settings import equal_settings, equal_settings_specs, quick_specs

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
