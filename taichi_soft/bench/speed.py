"""Steps per second of each integrator on the default cube dropped on the plane.

Method: build the scene once per (integrator, n, mode); warm up (Taichi compiles on the first
call); then ``repeats`` times: reset the state, advance ``chunk`` steps, ``ti.sync()``, read the
clock. Report the median. The cube falls onto the plane during the timed steps, so contact work
is included as in a real run.
"""
from __future__ import annotations

import statistics
import time

import taichi as ti

from ..forces import SLAB_STRIDE
from ..paths import ROOT
from ..scene import load_scene
from ..simulation import Simulation


def measure(integrator: str, n: int, mode: str = "auto", chunk: int | None = None, repeats: int = 5,
            scene: str = "plane") -> dict:
    """Median steps/s of ``integrator`` on an n^3 cube (edge 4 m, default springs, dt = 1 ms)."""
    sim = Simulation(load_scene(scene, [f"body.0.n={n}", "body.0.rotation.degrees=0"]), integrator=integrator,
                     options={"mode": mode})
    if chunk is None:
        # about 0.3 s of work per repeat on this machine's scale
        chunk = max(10, min(1000, int(3e7 / (n**3 * 13 * max(sim.integrator.force_evals, 1)))))
    sim.advance(2)  # compile
    ti.sync()
    times = []
    for _ in range(repeats):
        sim.reset()
        ti.sync()
        t0 = time.perf_counter()
        sim.advance(chunk)
        ti.sync()
        times.append(time.perf_counter() - t0)
        if sim.diverged:
            break
    med = statistics.median(times)
    return {
        "integrator": integrator, "n": n, "particles": n**3, "springs": sim.model.n_springs, "mode": "serial" if sim.integrator._serial() else "parallel",
        "forces": sim.integrator.forces.strategy if sim.integrator.forces else "-",
        "row_width": sim.integrator.forces.rows.width if sim.integrator.forces and sim.integrator.forces.rows else 0,
        "chunk": chunk, "repeats": len(times), "median_s": med, "steps_per_s": chunk / med,
        "ns_per_particle_step": med / chunk / n**3 * 1e9, "realtime_factor": chunk * sim.dt / med,
        "diverged": sim.diverged,
    }


def table(rows: list[dict]) -> str:
    out = ["| integrator | n | particles | launch | steps/s | ns / particle-step | x real time (dt = 1 ms) |",
           "|---|---:|---:|---|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['integrator']} | {r['n']} | {r['particles']} | {r['mode']} | {r['steps_per_s']:,.0f} | "
                   f"{r['ns_per_particle_step']:.1f} | {r['realtime_factor']:.2f} |")
    return "\n".join(out)


# -- references: numpy and NVIDIA Warp on the same cube and integrator -----------------------------
def compare_references(n: int, precision: str, chunk: int, repeats: int = 5) -> dict:
    """Semi-implicit Euler steps/s of the engine, numpy and (if installed) Warp on one n^3 cube.

    Scene: the default cube without terrain, started stretched (springs and dampers all working).
    All three take the same steps from the same state; their final states must agree (checked
    here and in the tests), so the ratios compare like with like.
    """
    import numpy as np

    from .references import NumpyStepper, WarpStepper, warp_available

    real = np.float64 if precision == "f64" else np.float32
    scene = load_scene("plane", [f"body.0.n={n}", "terrain.kind=none", "body.0.initial_stretch=[1.05, 0.97, 1.0]"])
    sim = Simulation(scene, integrator="semi_implicit_euler")
    x0, v0 = sim.model.x0_np, sim.model.v0_np
    out = {"n": n, "particles": n**3, "springs": sim.model.n_springs, "chunk": chunk, "precision": precision}

    def timed(reset, advance, sync):
        advance(2)  # warm-up: compiles
        sync()
        times = []
        for _ in range(repeats):
            reset()
            sync()
            t0 = time.perf_counter()
            advance(chunk)
            sync()
            times.append(time.perf_counter() - t0)
        return chunk / statistics.median(times)

    def sim_reset():
        sim.reset()

    out["engine_steps_per_s"] = timed(sim_reset, sim.advance, ti.sync)
    out["engine_mode"] = "serial" if sim.integrator._serial() else "parallel"
    engine_x = sim.state.x.to_numpy()

    nps = NumpyStepper(sim.model, x0, v0, sim.dt, real)

    def np_reset():
        nps.x[:] = x0
        nps.v[:] = v0

    np_chunk_scale = 1 if n <= 20 else 0.1  # numpy is slow: time fewer steps at large n
    c0 = chunk
    chunk = max(1, int(c0 * np_chunk_scale))
    out["numpy_steps_per_s"] = timed(np_reset, nps.step, lambda: None)
    chunk = c0
    np_reset()
    nps.step(chunk)
    out["max_abs_diff_numpy"] = float(np.abs(nps.x - engine_x).max())
    if warp_available():
        ws = WarpStepper(sim.model, x0, v0, sim.dt, precision, "cpu")

        def warp_reset():
            ws.x.assign(np.asarray(x0, real))
            ws.v.assign(np.asarray(v0, real))

        out["warp_cpu_steps_per_s"] = timed(warp_reset, ws.step, ws.sync)
        out["max_abs_diff_warp"] = float(np.abs(ws.numpy()[0] - engine_x).max())
        out["ratio_engine_over_warp_cpu"] = out["engine_steps_per_s"] / out["warp_cpu_steps_per_s"]
    out["ratio_engine_over_numpy"] = out["engine_steps_per_s"] / out["numpy_steps_per_s"]
    return out


# -- memory bandwidth bound ------------------------------------------------------------------------
def measured_bandwidth(mbytes: int = 256, repeats: int = 5) -> float:
    """Copy bandwidth [bytes/s] of a parallel Taichi kernel over two ``mbytes`` MB f32 fields."""
    n = mbytes * 2**20 // 4
    src = ti.field(ti.f32, n)
    dst = ti.field(ti.f32, n)

    @ti.kernel
    def copy():
        for i in src:
            dst[i] = src[i]

    return 2 * n * 4 / median_kernel_seconds(copy, repeats)


def median_kernel_seconds(kernel, repeats: int) -> float:
    """Median wall seconds of ``kernel()`` after one warm-up call (compiles), synced each time."""
    kernel()
    ti.sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        kernel()
        ti.sync()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bytes_per_step(n_particles: int, n_springs: int, real_bytes: int, strategy: str, row_width: int = 0) -> int:
    """Compulsory memory traffic [bytes] of one semi-implicit Euler step (each array touched once).

    Particles: read x, v; write x, v; the force sum (scatter: written by the spring pass, read
    and cleared by the particle pass; per_spring, gather: the particle pass's own sum, free);
    inverse mass. Per spring: (k, kd). ``scatter``: ends (2 i32), rest length.
    ``per_spring``: ends, rest length, the spring force written and read; adjacency: 1 i32 per
    spring end plus offsets and splits. ``gather``: per slot of its padded rows (``row_width``
    per particle, rows.py) the other end (i32), rest length and (k, kd).
    """
    vec = 3 * real_bytes
    particles = n_particles * (4 * vec + real_bytes)
    if strategy == "scatter":
        return particles + n_particles * 2 * vec + n_springs * (8 + 3 * real_bytes)
    if strategy == "per_spring":
        springs = n_springs * (8 + 3 * real_bytes + 2 * vec) + 2 * n_springs * 4 + 2 * n_particles * 4
    else:
        springs = n_particles * row_width * (4 + 3 * real_bytes)
    return particles + springs


# -- how well two threads overlap on this machine ---------------------------------------------------
def thread_overlap(task_ms=(0.3, 1.0, 3.0, 10.0), repeats=21) -> list[dict]:
    """Overlap in time of the two tasks of one parallel loop, per task length (CPU backend, >= 2 threads).

    A loop whose two tasks each spin for ``task_ms`` runs in 1x the time of one task when both
    threads start at once, 2x when the second thread joins only after the first has done both.
    ``overlap`` = 2 - median(two tasks) / median(one task): 1 perfect, 0 none. The thread scaling of
    the step kernels cannot beat what this allows for loops of their length: on virtual machines
    the second vCPU may wake up late (measured on the 2-core development VM: docs/benchmarks).
    """
    spin, arg = _overlap_kernel()

    def median_s(tasks, count):
        arg[0], arg[1] = tasks, count
        return median_kernel_seconds(spin, repeats)

    if "per_k" not in _OVERLAP:  # seconds per spin iteration, measured once per process
        _OVERLAP["per_k"] = median_s(1, 100000) / 100000
    per_k = _OVERLAP["per_k"]
    rows = []
    for ms in task_ms:
        count = max(1, int(ms * 1e-3 / per_k))
        one, two = median_s(1, count), median_s(2, count)
        rows.append({"task_ms": one * 1e3, "two_tasks_ms": two * 1e3, "overlap": 2.0 - two / one})
    return rows


_OVERLAP = {}  # this process's overlap kernel, its argument field (compiled once) and spin rate


def _overlap_kernel():
    """(kernel, arg): the kernel runs arg[0] tasks of one parallel loop, each spinning arg[1] times."""
    if not _OVERLAP:
        stride = SLAB_STRIDE  # one real task per stride iterations, as the parallel scatter's slabs
        sink = ti.field(ti.f32, 2)
        arg = ti.field(ti.i32, 2)  # tasks, spin count (fields: this module's annotations are strings)

        @ti.kernel
        def spin():
            for t in range(arg[0] * stride):
                if t % stride == 0:
                    acc = 0.0
                    for k in range(arg[1]):
                        acc = ti.sin(acc + k)
                    sink[t // stride] = acc

        _OVERLAP.update(kernel=spin, arg=arg, sink=sink)
    return _OVERLAP["kernel"], _OVERLAP["arg"]


# -- kernel profile ------------------------------------------------------------------------------------
def kernel_profile(integrator: str, n: int, steps: int = 50) -> list[dict]:
    """Per-task times of one integrator's parallel step (needs ``kernel_profiler=True`` at init).

    Taichi names each parallel loop of a kernel ``<kernel>_kernel_<k>_range_for``, k in source order
    (for ``semi_implicit_euler`` with gather forces: 1 = forces, 2 = update and collision).
    """
    from taichi.profiler.kernel_profiler import get_default_kernel_profiler

    sim = Simulation(load_scene("plane", [f"body.0.n={n}", "body.0.rotation.degrees=0"]), integrator=integrator,
                     options={"mode": "parallel"})
    sim.advance(5)
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    sim.advance(steps)
    ti.sync()
    prof = get_default_kernel_profiler()
    prof._update_records()  # noqa: SLF001 - Taichi 1.7 exposes per-task statistics only here
    prof._count_statistics()  # noqa: SLF001
    stats = prof._statistical_results  # noqa: SLF001
    total = sum(s.total_time for name, s in stats.items() if name.startswith("_advance_parallel"))
    rows = []
    for name, s in stats.items():
        if name.startswith("_advance_parallel"):
            rows.append({"task": name.split("_kernel_", 1)[-1], "calls": s.counter, "ms_per_step": s.total_time / steps,
                         "share": s.total_time / total if total else 0.0})
    return rows


# -- equal settings, interleaved: engine f32/f64 x fast math, numpy, Warp; thread scaling ----------
# Each configuration needs its own Taichi runtime (precision, fast math and thread count are fixed
# at ti.init), so each runs in a worker process that builds its stepper, compiles and warms up,
# then times one repeat whenever the coordinator asks. The coordinator asks the workers in turn,
# round after round (one running at a time), so slow drifts of the machine's load hit every
# configuration alike and the ratios come from one run.
REFERENCE_SCENE = ["terrain.kind=none", "body.0.initial_stretch=[1.05, 0.97, 1.0]"]
RUN_FPS = 30  # output frames per second of the "run" rows (the scene files' default)
REPEAT_SECONDS = 0.25  # work per timed repeat
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


class _Stepper:
    """One configuration inside a worker: ``reset()``, ``advance(k)``, ``sync()``, ``x()``."""

    def __init__(self, spec: dict):
        import numpy as np

        from .. import runtime

        kind, precision = spec["kind"], spec["precision"]
        init_kw = {}
        if spec.get("threads"):
            init_kw["cpu_max_num_threads"] = int(spec["threads"])
        if kind in ("engine", "run", "yardstick"):
            runtime.init(spec["arch"], precision, fast_math=spec["fast_math"], **init_kw)
        else:  # the model (numpy arrays, spring parameters) comes from the engine's builder
            runtime.init("cpu", precision)
        # "run": the user's path, Simulation.run on the plane terrain (as `run` without a video)
        sets = REFERENCE_SCENE[1:] if kind == "run" else REFERENCE_SCENE
        scene = load_scene("plane", [f"body.0.n={spec['n']}", *sets])
        self.sim = Simulation(scene, integrator="semi_implicit_euler")
        self.springs = self.sim.model.n_springs
        self.evals = self.springs  # spring evaluations per step (a gather evaluates each twice)
        model, x0, v0, dt = self.sim.model, self.sim.model.x0_np, self.sim.model.v0_np, self.sim.dt
        real = np.float64 if precision == "f64" else np.float32
        self.kind = kind
        self.mode = ""
        if kind in ("engine", "run"):
            self.reset, self.advance, self.sync = self.sim.reset, self.sim.advance, ti.sync
            if kind == "run":
                self.advance = lambda k: self.sim.run(k * dt, RUN_FPS, progress=lambda done, total, s: None).steps
            self.x = lambda: self.sim.state.x.to_numpy()
            forces = self.sim.integrator.forces.strategy
            self.mode = ("serial" if self.sim.integrator._serial() else "parallel") + f", {forces}"
            if forces == "gather":
                self.evals = 2 * self.springs
        elif kind == "yardstick":
            from .references import YardstickStepper

            ys = YardstickStepper(model, x0, v0, dt)
            self.reset, self.advance, self.sync = (lambda: ys.set(x0, v0)), ys.step, ti.sync
            self.x = lambda: ys.numpy()[0]
            self.mode, self.evals = "parallel, CSR gather", 2 * self.springs
        elif kind == "numpy":
            from .references import NumpyStepper

            nps = NumpyStepper(model, x0, v0, dt, real)

            def reset():
                nps.x[:] = x0
                nps.v[:] = v0
            self.reset, self.advance, self.sync, self.x = reset, nps.step, (lambda: None), (lambda: nps.x.copy())
        else:
            from .references import WarpStepper

            ws = WarpStepper(model, x0, v0, dt, precision, spec["arch"], fast_math=spec["fast_math"])

            def reset():
                ws.x.assign(np.asarray(x0, real))
                ws.v.assign(np.asarray(v0, real))
            self.reset, self.advance, self.sync, self.x = reset, ws.step, ws.sync, (lambda: ws.numpy()[0])

    def calibrate(self) -> int:
        """Warm up (compile), then the step count of about REPEAT_SECONDS of work."""
        self.advance(2)
        self.sync()
        k = 1
        while True:
            t = self.timed(k)
            if t > 0.05 or k >= 4096:
                t = min(t, self.timed(k), self.timed(k))  # a load spike must not shrink the chunk
                return max(1, min(20000, round(k * REPEAT_SECONDS / max(t, 1e-9))))
            k *= 4

    def timed(self, chunk: int, cpu: bool = False):
        """Wall seconds of ``chunk`` steps from the start state (and this process's CPU seconds)."""
        self.reset()
        self.sync()
        c0, t0 = time.process_time(), time.perf_counter()
        self.advance(chunk)
        self.sync()
        wall, used = time.perf_counter() - t0, time.process_time() - c0
        return (wall, used) if cpu else wall


def _worker_main():
    """Worker loop: one JSON spec as argv[1]; then commands on stdin, one JSON answer per line."""
    import json
    import sys

    import numpy as np

    spec = json.loads(sys.argv[1])
    out = sys.stdout
    sys.stdout = sys.stderr  # only the protocol goes to the real stdout
    try:
        st = _Stepper(spec)
        chunk = st.calibrate()
    except Exception as e:  # noqa: BLE001 - reported to the coordinator, which reports it
        print(json.dumps({"error": f"{type(e).__name__}: {e}"}), file=out, flush=True)
        return
    print(json.dumps({"chunk": chunk, "springs": st.springs, "evals": st.evals, "mode": st.mode}), file=out,
                     flush=True)
    for line in sys.stdin:
        cmd = line.split()
        if not cmd or cmd[0] == "quit":
            break
        if cmd[0] == "run":
            wall, used = st.timed(chunk, cpu=True)
            print(json.dumps({"s": wall, "cpu_s": used}), file=out, flush=True)
        elif cmd[0] == "overlap":  # overlap MS: thread_overlap of two MS-millisecond tasks, now
            print(json.dumps({"overlap": thread_overlap((float(cmd[1]),), repeats=5)[0]["overlap"]}), file=out,
                  flush=True)
        elif cmd[0] == "state":  # state STEPS PATH: the positions after STEPS steps from the start
            st.reset()
            st.advance(int(cmd[1]))
            st.sync()
            np.save(cmd[2], np.asarray(st.x(), np.float64))
            print(json.dumps({"ok": True}), file=out, flush=True)


class _Worker:
    def __init__(self, spec: dict):
        import json
        import subprocess
        import sys

        self.spec = spec
        self.proc = subprocess.Popen([sys.executable, "-m", "taichi_soft.bench.speed", json.dumps(spec)],
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


if __name__ == "__main__":
    _worker_main()
