"""Steps per second of each integrator on the default cube dropped on the plane.

Method: build the scene once per (integrator, n, mode); warm up (Taichi compiles on the first
call); then ``repeats`` times: reset the state, advance ``chunk`` steps, ``ti.sync()``, read the
clock. Report the median. The cube falls onto the plane during the timed steps, so contact work
is included as in a real run.

Also here: the same step against numpy and Warp (``compare_references``) and the per-task kernel
profile of a step (``kernel_profile``). What the machine allows (bandwidth bound, thread overlap)
is in ``machine_limits``; the interleaved equal-settings study in ``equal_settings``.
"""
from __future__ import annotations

import statistics
import time

import taichi as ti

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
