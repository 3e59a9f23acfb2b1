"""Where the user's `run` loses against the kernel: `main.py run --scene plane --set body.0.n=N
--precision f32` (fast math, default forces) taken apart, then its steps timed bare.

    PYTHONPATH=. .venv/bin/python studies/run_path_study.py N DURATION [REPEATS] [cold]

``cold``: an empty kernel cache (a temporary directory), as a first run on a machine compiles.

One process does what ``commands/run.py`` does, with a clock read (after ``ti.sync()``) between
the parts: imports, Taichi's start, the scene and the simulation (model, integrator, start check),
``Simulation.run`` chunk by chunk (the first launch compiles or loads the kernels, the first
parallel step finds the thread pool's workers), the summary. Then, in the same process and on the
same simulation, interleaved (taichi_soft.timing: medians): ``advance`` of a fixed chunk from the
start (the kernel, as ``bench speed`` times it), the same through ``Simulation.run`` with the
command line's progress callback, and the kernel on the equal-settings study's scene (no terrain,
started stretched). Prints one JSON line. Results: docs/benchmarks/STENCIL.md.
"""
import json
import sys
import time

T0 = time.perf_counter()
CPU0 = time.process_time()


def main(n: int, duration: float, repeats: int = 7, cold: bool = False) -> dict:
    import tempfile

    import taichi as ti

    from taichi_soft import compile_notice, cpu_threads, runtime
    from taichi_soft.progress import CountBar
    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import Simulation, step_count

    out = {"n": n, "duration_s": duration, "load_start": open("/proc/loadavg").read().split()[:3]}
    marks = [("imports", time.perf_counter())]

    def mark(name):
        ti.sync()
        marks.append((name, time.perf_counter()))

    extra = {"offline_cache_file_path": tempfile.mkdtemp()} if cold else {}
    runtime.init("cpu", "f32", fast_math=True, pin_threads=runtime.PIN_THREADS_CLI_DEFAULT, **extra)
    compile_notice.install(ti.lang.impl.current_cfg().offline_cache_file_path)  # as the command line does
    finding = {"s": 0.0}
    find = cpu_threads.find_pool_workers

    def timed_find():
        t = time.perf_counter()
        try:
            return find()
        finally:
            finding["s"] += time.perf_counter() - t
    cpu_threads.find_pool_workers = timed_find
    mark("taichi_start")
    scene = load_scene("plane", [f"body.0.n={n}", f"sim.duration={duration}"])
    sim = Simulation(scene)
    mark("simulation_built")
    out["forces"] = sim.integrator.forces.strategy
    out["mode"] = sim.integrator.mode
    total = step_count(duration, sim.dt)
    bar = CountBar(total, "study", unit="step")
    chunks = []

    def progress(done, _total, s):
        chunks.append((done, time.perf_counter(), time.process_time()))
        bar.update(done, f"t={s.time:6.3f}s")

    t_run, c_run = time.perf_counter(), time.process_time()
    first_launches = compile_notice._state["seconds"]  # noqa: SLF001 - the set-up's first launches
    result = sim.run(duration, scene.data["render"]["fps"], progress=progress)
    bar.close()
    mark("run")
    summary = sim.summary(result)
    mark("summary")
    out["parts_s"] = {name: t - marks[i][1] for i, (name, t) in enumerate(marks[1:])}
    out["parts_s"]["imports"] = marks[0][1] - T0
    out["reported_steps_per_s"] = summary["steps_per_second"]
    out["run_first_launches_s"] = compile_notice._state["seconds"] - first_launches  # noqa: SLF001
    out["run_pool_finding_s"] = finding["s"]
    prev_done, prev_t, prev_c = 0, t_run, c_run
    out["chunks"] = []  # (steps, wall s, CPU s) of each launch group of the run
    for done, t, c in chunks:
        out["chunks"].append((done - prev_done, t - prev_t, c - prev_c))
        prev_done, prev_t, prev_c = done, t, c
    first_steps, first_s, _ = out["chunks"][0]
    rest_steps = result.steps - first_steps
    rest_cpu = sum(c for _, _, c in out["chunks"][1:])
    out["run_after_first_chunk_steps_per_s"] = rest_steps / (result.wall_seconds - first_s)
    out["run_after_first_chunk_steps_per_cpu_s"] = rest_steps / rest_cpu
    out["run_chunk_sizes"] = sorted({k for k, _, _ in out["chunks"]})
    del out["chunks"]

    # The same simulation timed bare, interleaved with its run path; and the study's scene.
    from taichi_soft.timing import Candidate, time_candidates

    chunk = max(16, int(round(0.5 * rest_steps / (result.wall_seconds - first_s))))  # about 0.5 s of steps
    ref = Simulation(load_scene("plane", [f"body.0.n={n}", "terrain.kind=none",
                                          "body.0.initial_stretch=[1.05, 0.97, 1.0]"]), integrator="semi_implicit_euler")
    cands = {
        "kernel": Candidate(run=lambda: sim.advance(chunk), setup=sim.reset, warmup=lambda: sim.advance(2)),
        "via_run": Candidate(run=lambda: sim.run(chunk * sim.dt, 30, progress=lambda d, t, s: None), setup=sim.reset,
                             warmup=lambda: sim.advance(2)),
        "equal_settings_scene": Candidate(run=lambda: ref.advance(chunk), setup=ref.reset,
                                        warmup=lambda: ref.advance(2)),
    }
    res = time_candidates(cands, repeats)
    out["chunk"] = chunk
    out["steady_steps_per_s"] = {k: chunk / t.median for k, t in res.items()}
    out["steady_steps_per_cpu_s"] = {k: chunk / float(sorted(t.cpu)[len(t.cpu) // 2]) for k, t in res.items()}
    out["process_wall_s"] = time.perf_counter() - T0
    out["process_cpu_s"] = time.process_time() - CPU0
    out["load_end"] = open("/proc/loadavg").read().split()[:3]
    return out


if __name__ == "__main__":
    args = sys.argv[1:]
    cold = "cold" in args
    args = [a for a in args if a != "cold"]
    print(json.dumps(main(int(args[0]), float(args[1]), *(int(a) for a in args[2:]), cold=cold)))
