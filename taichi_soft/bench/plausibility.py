"""Plausibility at the frame steps people use interactively: 1/30 and 1/60 s.

``bench precision`` asks how far a trajectory is from the truth; at a frame step a viewer asks
whether the motion looks physical. Per implicit solver, settings (``precision.TOLERANCES``),
stiffness and step, two runs of the study's cube (``precision.cube_sets``):

* the flat drop of ``bench precision``: ``energy_rise`` the largest rise of the total energy
  (kinetic + gravity + springs) above its running minimum, relative to the largest |E| (0 when the
  step never gains energy); ``deepest_inside_m`` the deepest particle inside the terrain;
  ``apex`` / ``ref_apex`` the centre of mass's first bounce apex against the reference's (RK4 at
  1/64 of its limit, the study's reference task); ``rest_height`` / ``ref_rest_height``;
  ``rest_time`` / ``ref_rest_time`` when the centre of mass comes to rest (``precision.rest_time``);
* a push: the cube resting face down on the plane, given ``PUSH_SPEED`` along x. Coulomb friction
  stops a rigid block after v^2 / (2 mu g) (``slide_expected_m``); ``slide_m`` is how far the
  centre of mass went until it came to rest (or the run's end).

Steps counted: energy-clamped, failed (line search), and unconverged (ended with a residual above
``UNCONVERGED_FACTOR`` times the tolerance: iteration cap or stalled updates), over both runs.
"""
from __future__ import annotations

import math

import numpy as np

from . import precision as P
from .energy import relative_rise

STEPS = (1.0 / 30.0, 1.0 / 60.0)  # [s] the frame steps of interactive use
SOLVERS = ("implicit_euler", "fast_mass_spring")
SETTINGS = ("default", "tight", "bdf2", "sdirk2")
PUSH_SPEED = 3.0  # [m/s] initial sliding speed of the push
PUSH_TIME = 2.0  # [s] (the block stops after v / (mu g) = 1.0 s at mu 0.3)


def push_run(quick: bool) -> tuple[str, list[str], float]:
    """(scene, overrides, end time [s]) of the push: face down on the plane, moving along x."""
    sets = P.cube_sets(quick)
    size = float(sets[1].split("=")[1])
    centre = P.PLANE_Y + size / 2
    return ("plane", sets + [f"body.0.center=[0, {centre}, 0]", "body.0.rotation.degrees=0",
                             f"body.0.velocity=[{PUSH_SPEED}, 0, 0]"], 1.0 if quick else PUSH_TIME)


def _energy_run(sim, dt: float, t_end: float) -> dict:
    """Step by step from the scene's start: energies, penetration and the centre of mass."""
    sim.reset()
    sim.set_dt(dt)
    sim.integrator.stats()
    first = sim.measure()
    energies, inside, com, diverged = [first["total_energy"]], 0.0, [first["center_of_mass"]], False
    for _ in range(int(round(t_end / dt))):
        sim.advance(1)
        if sim.diverged:
            diverged = True
            break
        m = sim.measure()
        energies.append(m["total_energy"])
        inside = max(inside, -m["min_terrain_distance"])
        com.append(m["center_of_mass"])
    stats = sim.integrator.stats()
    return {"energies": np.asarray(energies), "rise": max(relative_rise(energies), 0.0), "inside": max(inside, 0.0),
            "com": np.asarray(com), "times": dt * np.arange(len(com)), "diverged": diverged, "stats": stats}


def task(name: str, scales, refs: dict, quick: bool) -> list[dict]:
    """One row per (settings, stiffness, step) of implicit solver ``name`` (a task of ``bench precision``)."""
    P._task_runtime()
    (scene, sets, t_end), = P.case_runs("flat", quick)
    push_scene, push_sets, push_end = push_run(quick)
    rows = []
    for setting in (P.QUICK_TOLERANCES if quick else SETTINGS):
        options = P.TOLERANCES[setting].get(name, {})
        drop, push = P.build(scene, sets, name, options), P.build(push_scene, push_sets, name, options)
        bases = [s.model.group_k.to_numpy().copy() for s in (drop, push)]
        mu = float(drop.terrain.friction[None])
        g = float(np.linalg.norm(drop.model.gravity.to_numpy()))
        for scale in scales:
            ref = refs[f"flat/{scale:g}"]["members"][0]["summary"]
            for sim, base in zip((drop, push), bases):
                P.set_stiffness(sim, scale, base)
            for dt in STEPS:
                d = _energy_run(drop, dt, t_end)
                s = _energy_run(push, dt, push_end)
                h = d["com"][:, 1] - P.PLANE_Y
                row = {"integrator": name, "settings": setting, "stiffness_scale": scale, "dt": dt,
                       "diverged": d["diverged"] or s["diverged"], "energy_rise": d["rise"],
                       "deepest_inside_m": max(d["inside"], s["inside"]),
                       "apex": P.first_apex(d["times"], h), "ref_apex": ref["apex"],
                       "rest_height": float(h[-1]), "ref_rest_height": ref["rest_height"],
                       "rest_time": P.rest_time(d["times"], d["com"]), "ref_rest_time": ref["rest_time"],
                       "slide_m": slide_distance(s), "slide_expected_m": PUSH_SPEED**2 / (2.0 * mu * g),
                       "energy_clamped_steps": int(d["stats"]["energy_clamped_steps"]) + int(s["stats"]["energy_clamped_steps"]),
                       "failed_solve_steps": int(d["stats"]["failed_solve_steps"]) + int(s["stats"]["failed_solve_steps"]),
                       "unconverged_steps": int(d["stats"]["unconverged_steps"]) + int(s["stats"]["unconverged_steps"]),
                       "steps": int(d["stats"]["steps"]) + int(s["stats"]["steps"])}
                rows.append(row)
        for sim, base in zip((drop, push), bases):
            P.set_stiffness(sim, 1.0, base)
    return rows


def slide_distance(run: dict) -> float:
    """Distance [m] along x the push's centre of mass went until it came to rest (nan if diverged)."""
    if run["diverged"]:
        return math.nan
    x = run["com"][:, 0]
    t = P.rest_time(run["times"], run["com"])
    k = len(x) - 1 if not math.isfinite(t) else int(round(t / (run["times"][1] - run["times"][0])))
    return float(x[min(k, len(x) - 1)] - x[0])


def markdown(rows: list[dict]) -> list[str]:
    """The plausibility table (REPORT.md / PRECISION.md section)."""
    out = ["## Plausibility at frame steps (1/30 and 1/60 s)", "", __doc__.split("\n\n", 1)[1].strip(), "",
           "| solver | settings | stiffness | dt [s] | energy rise | deepest inside [m] | apex / reference [m] "
           "| rest height / reference [m] | at rest / reference [s] | slide / v^2/(2 mu g) [m] "
           "| clamped / failed / unconverged / all steps |",
           "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        if r["diverged"]:
            out.append(f"| {r['integrator']} | {r['settings']} | x{r['stiffness_scale']:g} | 1/{1 / r['dt']:.0f} | diverged |"
                       " | | | | | |")
            continue
        out.append(f"| {r['integrator']} | {r['settings']} | x{r['stiffness_scale']:g} | 1/{1 / r['dt']:.0f} | "
                   f"{r['energy_rise']:.1e} | {r['deepest_inside_m']:.1e} | "
                   f"{_m(r['apex'])} / {_m(r['ref_apex'])} | {_m(r['rest_height'])} / {_m(r['ref_rest_height'])} | "
                   f"{_m(r.get('rest_time'))} / {_m(r.get('ref_rest_time'))} | "
                   f"{_m(r['slide_m'])} / {_m(r['slide_expected_m'])} | "
                   f"{r['energy_clamped_steps']} / {r['failed_solve_steps']} / {r['unconverged_steps']} / {r['steps']} |")
    return out


def _m(x) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.2f}"
