"""``run --dry-run``: what a run would simulate and write, and the memory it would take.

Nothing is simulated, written or probed, and Taichi is not started: the lines come from the
validated scene, the step count the run would take and the memory estimate ``check_fits`` uses.
"""
from __future__ import annotations

from .sim import memory
from .sim.simulation import frame_steps, step_count


def _size(b: int) -> str:
    return f"{b / 1e6:.0f} MB" if b < 1e9 else f"{b / 1e9:.2f} GB"


def describe(scene, precision: str, arch: str, outputs: dict, fps: float, fast_math: bool = True) -> list[str]:
    """Lines for ``run --dry-run``: ``scene`` a validated ``Scene``; ``outputs`` {flag: path or
    None}; ``fps`` the output frame rate."""
    sim, data = scene.sim, scene.data
    dt, duration = sim["dt"], sim["duration"]
    steps = step_count(duration, dt)
    frames = len(frame_steps(steps, fps, dt))
    bodies = data["body"]
    e = memory.estimate(data, None, precision, arch, record_states=outputs.get("--states") is not None,
                        fast_math=fast_math)
    have = memory.available_bytes(arch)
    lines = [
        f"dry run of {scene.label}: nothing is simulated or written",
        f"  integrator {sim['integrator']}, dt = {dt:g} s, duration {duration:g} s: {steps} steps, "
        f"{frames} frames at {fps:g} fps",
        f"  {len(bodies)} bod{'y' if len(bodies) == 1 else 'ies'} "
        f"(n = {', '.join(str(b['n']) for b in bodies)}): {e['particles']:,} particles, {e['springs']:,} springs; "
        f"terrain {data['terrain']['kind']}",
        f"  {precision} on {e['arch']}: memory estimate {_size(e['host'])} host"
        + (f" + {_size(e['device'])} device" if e["device"] else "")
        + f" (fields {_size(e['fields'])})"
        + (f"; {_size(have)} available" if have is not None else ""),
    ]
    wanted = [f"{flag} {path}" for flag, path in outputs.items() if path is not None]
    lines.append("  would write: " + (", ".join(wanted) if wanted else "nothing (no output flag given)"))
    return lines
