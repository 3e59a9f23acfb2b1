"""Steps per second of each integrator on the default cube dropped on the plane.

Method: build the scene once per (integrator, n, mode); then ``timing.time_one``: warm up
(Taichi compiles on the first call), ``repeats`` times reset the state and time ``chunk`` steps
(``ti.sync()`` before each clock reading). Report the median. The cube falls onto the plane
during the timed steps, so contact work is included as in a real run.

Also here: the per-task kernel profile of a step (``kernel_profile``). What the machine allows
(bandwidth bound, thread overlap) is in ``machine_limits``; the interleaved equal-settings study
in ``equal_settings``.
"""
from __future__ import annotations

import taichi as ti

from ..sim.scene import load_scene
from ..sim.simulation import Simulation
from ..timing import time_one


def measure(integrator: str, n: int, mode: str = "auto", chunk: int | None = None, repeats: int = 5,
            scene: str = "plane") -> dict:
    """Median steps/s of ``integrator`` on an n^3 cube (edge 4 m, default springs, dt = 1 ms)."""
    sim = Simulation(load_scene(scene, [f"body.0.n={n}", "body.0.rotation.degrees=0"]), integrator=integrator,
                     options={"mode": mode})
    if chunk is None:
        # about 0.3 s of work per repeat on this machine's scale
        chunk = max(10, min(1000, int(3e7 / (n**3 * 13 * max(sim.integrator.force_evals, 1)))))
    t = time_one(lambda: sim.advance(chunk), repeats, setup=sim.reset, warmup=lambda: sim.advance(2),  # compiles
                 done=lambda _: sim.diverged)
    med = t.median
    return {
        "integrator": integrator, "n": n, "particles": n**3, "springs": sim.model.n_springs, "mode": "serial" if sim.integrator._serial() else "parallel",
        "forces": sim.integrator.forces.strategy if sim.integrator.forces else "-",
        "row_width": sim.integrator.forces.rows.width if sim.integrator.forces and sim.integrator.forces.rows else 0,
        "chunk": chunk, "repeats": t.repeats, "median_s": med, "steps_per_s": chunk / med,
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
