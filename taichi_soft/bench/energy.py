"""``python main.py bench energy``: the implicit solvers' energy matrix.

An implicit step minimises an objective whose value bounds the energy the step ends with, so on
undamped-or-damped soft bodies with inelastic contact the total energy must never rise above its
running minimum. The matrix checks that where it is hardest:

* one body: both implicit solvers x the four terrains x stiffness x1, x10, x100, x1000 x dt 1/60,
  1/30 and 0.1 s, the default cube's 3-s drop with the contact defaults;
* two bodies: both solvers x ``three_cubes`` and ``pile`` x the same steps, the total counting the
  pairs' penalty energy at each step's end (``pair_energy``; what each step's start counted as
  refrozen is reported beside, not taken off).

Per case: the largest rise of the total energy above its running minimum, relative to the largest
|E| (a case is clean at 1e-9 or below), divergence, the energy clamp's count, the deepest particle
inside the terrain and the deepest overlap between bodies, and the candidate pairs that did not fit
the pair list (``health``). ``quick`` (what the tests run): implicit_euler on a 3^3 cube and
fast_mass_spring on three_cubes made of 4^3 cubes, x1, 1/30 s, 1 s.

(Before this study the matrix was ``scripts/bench/matrix11.py``; its numbers in docs/benchmarks/IMPLICIT.md
are pinned to the commits they name.)
"""
from __future__ import annotations

import numpy as np

SOLVERS = ("implicit_euler", "fast_mass_spring")
TERRAINS = ("plane", "tilted_plane", "sphere", "bowl")
SCALES = (1.0, 10.0, 100.0, 1000.0)
STEPS = (1 / 60, 1 / 30, 0.1)  # [s]
SCENES = ("three_cubes", "pile")
HORIZON = 3.0  # [s]
CLEAN = 1e-9  # largest rise above the running minimum, relative to max |E|, of a clean case


def cases(quick: bool) -> list[dict]:
    """Every case of the matrix: {solver, scene, sets, stiffness_scale, dt, horizon}."""
    if quick:
        # One case per solver (each case compiles its own simulation): backward Euler on one body,
        # fast_mass_spring on three bodies.
        return [{"solver": "implicit_euler", "scene": "plane", "sets": ["body.0.n=3"], "stiffness_scale": 1.0,
                 "dt": 1 / 30, "horizon": 1.0},
                {"solver": "fast_mass_spring", "scene": "three_cubes", "sets": [f"body.{b}.n=4" for b in range(3)],
                 "stiffness_scale": 1.0, "dt": 1 / 30, "horizon": 1.0}]
    out = [{"solver": s, "scene": t, "sets": [], "stiffness_scale": k, "dt": dt, "horizon": HORIZON}
           for s in SOLVERS for t in TERRAINS for k in SCALES for dt in STEPS]
    out += [{"solver": s, "scene": t, "sets": [], "stiffness_scale": 1.0, "dt": dt, "horizon": HORIZON}
            for s in SOLVERS for t in SCENES for dt in STEPS]
    return out


def relative_rise(series) -> float:
    """The largest rise of an energy series above its running minimum, relative to its largest |E|
    (negative when it only fell; -inf for a single value)."""
    e = np.asarray(series, dtype=float)
    return float((e[1:] - np.minimum.accumulate(e)[:-1]).max(initial=-np.inf) / max(np.abs(e).max(), 1e-300))


def pair_energy(sim) -> float:
    """The body-body term of the energy balance [J] (0 for one body): the penalty energy the last
    step ended with (``pairs.py``: w kappa m_ij / (2 h^2) o^2 per pair in contact). Nothing is taken
    off for the geometry each step freezes anew at its start (``body_pair_energy_refrozen_J``, which
    the matrix reports beside): the balance holds with it (docs/benchmarks/ENERGY.md)."""
    pairs = getattr(sim.integrator, "pairs", None)
    if pairs is None:
        return 0.0
    return pairs.energy_terms()[0]


def _simulation(case: dict, sims: dict):
    """The simulation of ``case``'s solver, scene and overrides (built once into ``sims``) and its
    scene stiffnesses. One per run and key, reused across stiffness and dt: every new Simulation
    allocates its own fields, and a Taichi 1.7 runtime crashes (SIGSEGV) after too many field trees
    -- the full matrix building one per case died after about 100 of its 108 cases."""
    from ..sim.integrators import names
    from ..sim.scene import load_scene
    from ..sim.simulation import Simulation

    key = (case["solver"], case["scene"], tuple(case["sets"]))
    if key not in sims:
        sim = Simulation(load_scene(case["scene"], list(case["sets"]), integrator_names=names()), case["solver"],
                         case["dt"])
        sims[key] = (sim, sim.model.group_k.to_numpy()[: sim.model.n_groups].copy())
    return sims[key]


def run_case(case: dict, sims: dict) -> dict:
    """One row of the matrix (module doc), from the scene's initial state; ``sims`` holds the
    simulations already built in this run (``_simulation``)."""
    sim, base_k = _simulation(case, sims)
    sim.model.set_group_stiffness(base_k * case["stiffness_scale"])
    dt = case["dt"]
    sim.set_dt(dt)
    sim.reset()

    def energy():
        """(total energy with the pair terms [J], depth of the deepest particle inside the terrain [m])."""
        m = sim.measure()
        return m["total_energy"] + pair_energy(sim), -m["min_terrain_distance"]

    sim.integrator.stats()  # counters from here
    e0, _ = energy()
    series, inside, diverged = [e0], 0.0, False
    for _ in range(int(round(case["horizon"] / dt))):
        sim.advance(1)
        if sim.diverged:
            diverged = True
            break
        e, depth = energy()
        series.append(e)
        inside = max(inside, depth)
    rise = relative_rise(series)
    s = sim.integrator.stats()
    return {"solver": case["solver"], "scene": case["scene"], "stiffness_scale": case["stiffness_scale"], "dt": dt,
            "steps": int(s["steps"]), "rise": rise, "diverged": diverged,
            "clean": bool(not diverged and rise <= CLEAN), "energy_clamped_steps": int(s["energy_clamped_steps"]),
            "failed_solve_steps": int(s["failed_solve_steps"]), "deepest_inside_m": max(inside, 0.0),
            "deepest_overlap_m": s.get("body_deepest_overlap_m", 0.0),
            "refrozen_J": s.get("body_pair_energy_refrozen_J", 0.0),
            "pairs_dropped": int(s.get("body_pair_overflows", 0))}


def run(quick: bool, progress=None) -> dict:
    """Every case in turn, in this process (one Taichi runtime: the caller starts it)."""
    todo = cases(quick)
    rows, sims = [], {}
    try:
        for k, case in enumerate(todo):
            rows.append(run_case(case, sims))
            if progress:
                progress(k + 1, len(todo), f"{case['solver']} {case['scene']} dt {case['dt']:.4g}")
    except KeyboardInterrupt:
        return {"rows": rows, "interrupted": True, "quick": quick}
    return {"rows": rows, "interrupted": False, "quick": quick}


def markdown(result: dict) -> list[str]:
    """The matrix's Markdown: the verdict line, then every case that was not clean or needed the clamp."""
    rows = result["rows"]
    clean = sum(r["clean"] for r in rows)
    clamped = sum(r["energy_clamped_steps"] for r in rows)
    steps = sum(r["steps"] for r in rows)
    out = ["## Energy matrix (implicit solvers)", "",
           f"**{clean} of {len(rows)} cases clean** (no rise of the total energy above its running minimum beyond "
           f"{CLEAN:g} of its largest |E|){' (interrupted)' if result['interrupted'] else ''}; the energy clamp acted "
           f"on {clamped} of {steps} steps; deepest particle inside the terrain "
           f"{max((r['deepest_inside_m'] for r in rows), default=0.0):.3g} m; deepest overlap between bodies "
           f"{max((r['deepest_overlap_m'] for r in rows), default=0.0):.3g} m; body-body penalty energy counted as "
           f"refrozen at the steps' starts, the largest of a case {max((abs(r['refrozen_J']) for r in rows), default=0.0):.3g} J "
           "(counted in the total, not taken off: ``pair_energy``).", ""]
    notes = [r for r in rows if not r["clean"] or r["energy_clamped_steps"] or r["pairs_dropped"]]
    if notes:
        out += ["| solver | scene | stiffness | dt [s] | rise / max abs E | clamps | diverged | deepest overlap [m] | "
                "refrozen [J] | pairs dropped |", "|---|---|---:|---:|---:|---:|---|---:|---:|---:|"]
        out += [f"| {r['solver']} | {r['scene']} | x{r['stiffness_scale']:g} | {r['dt']:.4g} | {r['rise']:.2e} | "
                f"{r['energy_clamped_steps']}/{r['steps']} | {r['diverged']} | {r['deepest_overlap_m']:.3g} | "
                f"{r['refrozen_J']:.3g} | {r['pairs_dropped']} |" for r in notes]
        out.append("")
    return out
