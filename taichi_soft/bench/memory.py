"""``bench memory``: peak resident (and device) memory per particle, measured against the estimate.

Method: every (integrator, precision, n) runs ``main.py run --scene plane --set body.0.n=N`` for
one step in a fresh subprocess, which reports its own peak resident set size (``VmHWM`` from
/proc/self/status) and, on CUDA, the device memory nvidia-smi shows for it at the end of the run.
Implicit methods run with one Newton / global iteration and a few CG iterations: their memory does
not depend on the iteration counts, their time does. Each row carries ``taichi_soft.memory``'s
estimate for the same run, so the model that refuses too-large runs is checked here.

Sizes: n = 10, 20, 40, 80 and the largest n (up to the scene limit) whose estimate fits in
``FIT_FRACTION`` of the memory available when the study starts; ``quick`` (CI): three tiny runs.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

from .. import memory
from ..paths import ROOT
from ..scene import load_scene
from ..scene_validation import MAX_N

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

# Runs in the subprocess: the CLI's own run, then the process reports its peak memory.
_WORKER = r"""
import json, os, resource, subprocess, sys
sys.path.insert(0, sys.argv[1])
from taichi_soft.cli import main
args = json.loads(sys.argv[2])
with open(os.devnull, "w") as null:
    out, sys.stdout = sys.stdout, null
    rc = main(args["argv"])
    sys.stdout = out
peak = None
try:
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            peak = int(line.split()[1]) * 1024
except OSError:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
device = None
if args["arch"] == "cuda":
    try:
        q = subprocess.run(["nvidia-smi", "--query-compute-apps=pid,used_memory", "--format=csv,noheader,nounits"],
                           capture_output=True, text=True, timeout=20).stdout
        device = sum(int(l.split(",")[1]) for l in q.splitlines() if l.split(",")[0].strip() == str(os.getpid())) * 2**20
    except Exception:
        device = None
print(json.dumps({"rc": rc, "peak_bytes": peak, "device_bytes": device}))
"""


def scene_sets(n: int, integrator: str) -> list[str]:
    """The ``--set`` overrides of one measured run (the default plane scene, one body of n^3)."""
    return [f"body.0.n={n}"] + _FEW_ITERATIONS.get(integrator, [])


def measure_peak(n: int, integrator: str, precision: str = "f64", arch: str = "cpu", timeout: float = 1800,
                 env: dict | None = None) -> dict:
    """Peak resident bytes (and CUDA device bytes) of a one-step CLI run in a fresh process
    (``env``: extra environment variables for it)."""
    sets = scene_sets(n, integrator)
    argv = ["run", "--scene", "plane", "--integrator", integrator, "--precision", precision, "--arch", arch,
            "--dt", "0.001", "--duration", "0.001"]
    for s in sets:
        argv += ["--set", s]
    proc = subprocess.run([sys.executable, "-c", _WORKER, str(ROOT), json.dumps({"argv": argv, "arch": arch})],
                          capture_output=True, text=True, cwd=ROOT, timeout=timeout, env={**os.environ, **(env or {})})
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"memory run n={n} {integrator} {precision} failed: {proc.stderr.strip()[-500:]}")
    res = json.loads(lines[-1])
    if res["rc"] != 0:
        raise RuntimeError(f"memory run n={n} {integrator} {precision} exited {res['rc']}: {proc.stderr.strip()[-300:]}")
    data = load_scene("plane", sets).data
    est = memory.estimate(data, integrator, precision, arch)
    n_p, n_s = est["particles"], est["springs"]
    return {"integrator": integrator, "family": FAMILY.get(integrator, "explicit"), "precision": precision,
            "arch": est["arch"], "n": n, "particles": n_p, "springs": n_s, "peak_bytes": res["peak_bytes"],
            "device_bytes": res["device_bytes"], "estimate_host_bytes": est["host"],
            "estimate_device_bytes": est["device"], "measured_over_estimate": res["peak_bytes"] / est["host"],
            "bytes_per_particle": res["peak_bytes"] / n_p}


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
    rows, errors, interrupted = [], [], False
    for k, (integrator, precision, n) in enumerate(jobs):
        try:
            rows.append(measure_peak(n, integrator, precision, arch))
        except KeyboardInterrupt:
            interrupted = True
            break
        except (RuntimeError, subprocess.TimeoutExpired) as e:
            errors.append(str(e))
        if progress:
            progress(k + 1, len(jobs), f"memory {integrator} {precision} n={n}")
    return {"rows": rows, "errors": errors, "interrupted": interrupted, "fit_fraction": FIT_FRACTION,
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
           "process, against `taichi_soft/memory.py`'s estimate (the one `run` checks before it starts). "
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
