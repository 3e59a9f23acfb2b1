"""Equal settings, interleaved: engine f32/f64 x fast math, numpy, Warp; thread scaling.

Each configuration needs its own Taichi runtime (precision, fast math and thread count are fixed
at ti.init), so each runs in a worker process (``speed_worker``) that builds its stepper, compiles
and warms up, then times one repeat whenever the coordinator (``equal_settings`` here) asks. The
coordinator asks the workers in turn, round after round (one running at a time), so slow drifts of
the machine's load hit every configuration alike and the ratios come from one run.

Why not tasks (``taichi_soft.tasks``, the benchmarks' worker protocol elsewhere): a task runs one
function to completion in a fresh process and returns its value; interleaving needs every
configuration's process alive, compiled and warmed up, between its repeats. So the coordinator
talks to live workers, one JSON line per request on their stdin and stdout (``speed_worker``).
"""
from __future__ import annotations

import statistics

from ..paths import ROOT

OVERLAP_TASK_MS = 2.0  # task length of the overlap probe taken beside multi-threaded repeats


def quick_specs() -> list[dict]:
    """A 4^3 cube, f64: the engine with fast math off and on, and Warp (checks the machinery; each
    worker costs a Taichi start and a compile, so numpy is left to the full study)."""
    base = {"group": "n4", "arch": "cpu", "precision": "f64", "threads": None, "n": 4}
    return [{**base, "kind": "engine", "fast_math": False}, {**base, "kind": "engine", "fast_math": True},
            {**base, "kind": "warp", "fast_math": True}]


def equal_settings_specs(sizes=(10, 40), scaling_sizes=(40, 80), archs=("cpu",)) -> list[dict]:
    """Worker configurations: per size, the engine in f64/f32 with fast math off/on and numpy and
    Warp in f64/f32 (Warp with its fast_math module option); per scaling size, the engine with
    fast math at 1 and 2 threads. GPU archs add the engine and Warp there."""
    specs = []
    for n in sizes:
        for precision in ("f64", "f32"):
            for fm in (False, True):
                specs.append({"group": f"n{n}", "kind": "engine", "arch": "cpu", "precision": precision,
                              "fast_math": fm, "threads": None, "n": n})
            for kind in ("run", "yardstick"):  # the user's path; the plain Taichi kernel
                specs.append({"group": f"n{n}", "kind": kind, "arch": "cpu", "precision": precision,
                              "fast_math": True, "threads": None, "n": n})
            specs.append({"group": f"n{n}", "kind": "numpy", "arch": "cpu", "precision": precision, "n": n})
            specs.append({"group": f"n{n}", "kind": "warp", "arch": "cpu", "precision": precision,
                          "fast_math": True, "n": n})
            for arch in archs:
                if arch != "cpu":
                    specs.append({"group": f"n{n}", "kind": "engine", "arch": arch, "precision": precision,
                                  "fast_math": True, "threads": None, "n": n})
                    specs.append({"group": f"n{n}", "kind": "warp", "arch": arch, "precision": precision,
                                  "fast_math": True, "n": n})
    for n in scaling_sizes:
        for precision in ("f64", "f32"):
            for threads in (1, 2):
                specs.append({"group": f"threads_n{n}", "kind": "engine", "arch": "cpu", "precision": precision,
                              "fast_math": True, "threads": threads, "n": n})
                if precision == "f32":
                    specs.append({"group": f"threads_n{n}", "kind": "yardstick", "arch": "cpu",
                                  "precision": precision, "fast_math": True, "threads": threads, "n": n})
    return specs



class _Worker:
    def __init__(self, spec: dict):
        import json
        import subprocess
        import sys

        self.spec = spec
        self.proc = subprocess.Popen([sys.executable, "-m", "taichi_soft.bench.speed_worker", json.dumps(spec)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     cwd=str(ROOT))
        self.info = self._read()

    def _read(self) -> dict:
        import json

        line = self.proc.stdout.readline()
        if not line:
            err = self.proc.stderr.read().strip().splitlines()
            return {"error": (err[-1] if err else "worker exited")[:300]}
        return json.loads(line)

    def ask(self, cmd: str) -> dict:
        self.proc.stdin.write(cmd + "\n")
        self.proc.stdin.flush()
        return self._read()

    def close(self):
        try:
            self.proc.stdin.write("quit\n")
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout=30)
        except Exception:  # noqa: BLE001
            self.proc.kill()


def equal_settings(specs: list[dict], rounds: int = 5, check_steps: int = 20, progress=None) -> list[dict]:
    """Median steps/s of every spec, measured interleaved by group (specs with the same "group"
    run together: one timed repeat of each in turn, ``rounds`` times, the order rotated each
    round); also steps per CPU second of the worker process (all its threads), which a loaded
    machine distorts less than wall time. Also the max abs difference of each final state after ``check_steps`` steps from the
    group's first spec (the engine in f64 without fast math, or at one thread)."""
    import tempfile

    import numpy as np

    from .references import warp_available

    rows = []
    groups = list(dict.fromkeys(s["group"] for s in specs))
    for gi, group in enumerate(groups):
        members = [s for s in specs if s["group"] == group]
        workers = []
        try:
            for spec in members:  # started one after the other: compiling is not timed, but is busy
                if spec["kind"] == "warp" and not warp_available():
                    workers.append(None)
                    continue
                workers.append(_Worker(spec))
            live = [w for w in workers if w is not None and "error" not in w.info]
            times = {id(w): [] for w in live}
            cpu = {id(w): [] for w in live}
            overlap = {id(w): [] for w in live}
            for r in range(rounds):
                for w in live[r % max(len(live), 1):] + live[:r % max(len(live), 1)]:
                    answer = w.ask("run")
                    times[id(w)].append(answer["s"])
                    cpu[id(w)].append(answer["cpu_s"])
                    if _multithreaded(w.spec):
                        # Did the machine give this worker its threads at the same time, just now?
                        # Loops of about a step's pass, 1-2 ms at n = 40 (thread_overlap).
                        overlap[id(w)].append(w.ask(f"overlap {OVERLAP_TASK_MS}")["overlap"])
            finals = {}
            with tempfile.TemporaryDirectory() as tmp:
                for k, w in enumerate(live):
                    path = f"{tmp}/x{k}.npy"
                    w.ask(f"state {check_steps} {path}")
                    finals[id(w)] = np.load(path)
            ref = finals[id(live[0])] if live else None
            for spec, w in zip(members, workers):
                row = {k: spec.get(k) for k in ("group", "kind", "arch", "precision", "fast_math", "threads", "n")}
                row["particles"] = spec["n"] ** 3
                if w is None:
                    row["error"] = "warp-lang is not installed (pip install warp-lang)"
                elif "error" in w.info:
                    row["error"] = w.info["error"]
                else:
                    ts = times[id(w)]
                    med = statistics.median(ts)
                    chunk = w.info["chunk"]
                    row.update(mode=w.info["mode"], springs=w.info["springs"], chunk=chunk, repeats=len(ts),
                               steps_per_s=chunk / med, ns_per_spring=med / chunk / w.info["springs"] * 1e9,
                               ns_per_eval=med / chunk / w.info["evals"] * 1e9,
                               steps_per_cpu_s=chunk / max(statistics.median(cpu[id(w)]), 1e-9),
                               spread=(max(ts) - min(ts)) / med,
                               max_abs_diff=float(np.abs(finals[id(w)] - ref).max()))
                    if overlap[id(w)]:
                        row["thread_overlap"] = statistics.median(overlap[id(w)])
                rows.append(row)
        finally:
            for w in workers:
                if w is not None:
                    w.close()
        if progress:
            progress(gi + 1, len(groups), f"equal settings {group}")
    return rows


def _multithreaded(spec: dict) -> bool:
    """A worker whose steps run on several CPU threads (the thread-scaling rows at 2 threads)."""
    return spec["kind"] in ("engine", "yardstick") and spec["arch"] == "cpu" and (spec.get("threads") or 0) > 1


def find_row(rows, **key):
    """The row whose fields equal ``key`` (None if absent or failed)."""
    for r in rows:
        if all(r.get(k) == v for k, v in key.items()) and "error" not in r:
            return r
    return None
