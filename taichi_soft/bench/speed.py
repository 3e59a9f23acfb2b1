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

from ..integrators import REGISTRY
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
        "integrator": integrator, "n": n, "particles": n**3, "mode": "serial" if sim.integrator._serial() else "parallel",
        "chunk": chunk, "repeats": len(times), "median_s": med, "steps_per_s": chunk / med,
        "ns_per_particle_step": med / chunk / n**3 * 1e9, "realtime_factor": chunk * sim.dt / med,
        "diverged": sim.diverged,
    }


def sweep(sizes=(10, 20, 40), integrators=None, modes=("auto",), repeats=5, progress=None) -> list[dict]:
    rows = []
    names = integrators or [k for k, c in REGISTRY.items()]
    jobs = [(name, n, mode) for n in sizes for name in names for mode in modes]
    for k, (name, n, mode) in enumerate(jobs):
        rows.append(measure(name, n, mode, repeats=repeats))
        if progress:
            progress(k + 1, len(jobs), rows[-1])
    return rows


def table(rows: list[dict]) -> str:
    out = ["| integrator | n | particles | launch | steps/s | ns / particle-step | x real time (dt = 1 ms) |",
           "|---|---:|---:|---|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['integrator']} | {r['n']} | {r['particles']} | {r['mode']} | {r['steps_per_s']:,.0f} | "
                   f"{r['ns_per_particle_step']:.1f} | {r['realtime_factor']:.2f} |")
    return "\n".join(out)
