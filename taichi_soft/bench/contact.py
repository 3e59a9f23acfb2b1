"""``python main.py bench contact``: body-body contact, how it slides and what it costs.

* **slide**: a 1 m cube (n = 4) on a 3 m cube (n = 10, the same 1/3 m lattice spacing) resting on
  the plane, its faces inside the lower one's top face (centre x = -0.5 m of [-1.5, 1.5] m), settled
  for 1 s, then pushed to 1.5 m/s along x. The relative x velocity of the two centres of
  mass, sampled every 0.05 s, falls at mu g where the faces are flat; the fit runs over
  0.05-0.3 s (it stops after ~0.5 s at mu = 0.3). The plane's friction, the same mu (one
  ``contact.friction``), holds the lower cube, which carries both weights. Each solver at its own
  step: the implicit ones at 1/60 s, semi-implicit Euler at 1/960 s.
* **cost**: the pile scene for 4 s with the implicit solvers' body contact off and on
  (``solver.body_contact``; the explicit methods' contact pass has no switch) at 1/60 s, every
  kernel compiled first, the two runs interleaved (``timing.time_candidates``): the ratio of median
  wall times on / off, the deepest overlap between bodies, the pairs in contact and the solver's
  unconverged steps in the contact run.

``quick`` (what the tests run): fast_mass_spring only, the slide at mu = 0.3 and 2 s of the pile
(the first bodies have landed), 2 repeats.
"""
from __future__ import annotations

import numpy as np

G = 9.8  # [m/s^2], the scenes' gravity
PUSH = 1.5  # [m/s]
SETTLE = 1.0  # [s] at rest before the push
SAMPLE = 0.05  # [s] between velocity samples
SAMPLES = 16
FIT = (0.05, 0.3)  # [s] the deceleration's fit window
MUS = (0.0, 0.3)
SLIDE_RUNS = (("implicit_euler", 1 / 60), ("fast_mass_spring", 1 / 60), ("semi_implicit_euler", 1 / 960))
COST_RUNS = (("fast_mass_spring", 1 / 60), ("implicit_euler", 1 / 60))
TWO_CUBES = {"body": [{"n": 10, "size": 3.0, "center": [0.0, 1.5, 0.0]},
                      {"n": 4, "size": 1.0, "center": [-0.5, 3.0 + 0.5 + 1 / 3, 0.0]}],
             "terrain": {"kind": "plane", "point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0]}}


def slide(integrator: str, mu: float, dt: float, cubes: dict = TWO_CUBES, sims: dict | None = None) -> dict:
    """The slide (module doc) with ``integrator`` at step ``dt`` [s] and friction ``mu``: the
    fitted deceleration [m/s^2] against mu g (nan if the run diverged), the relative velocities
    [m/s], and the largest particle velocity component [m/s] when the push came (settled: small).
    ``cubes``: the scene, as ``TWO_CUBES`` (the lower body first); ``sims``: simulations built by
    earlier calls, reused from their initial state (each new one compiles its kernels again)."""
    from ..sim.integrators import names
    from ..sim.scene import scene_from_dict
    from ..sim.simulation import Simulation

    key = (integrator, dt, repr(cubes))
    sims = {} if sims is None else sims
    if key in sims:
        sim = sims[key]
        sim.reset()
    else:
        sim = sims[key] = Simulation(scene_from_dict(cubes, "two_cubes", integrator_names=names()),
                                     integrator=integrator, dt=dt)
    sim.terrain.set_contact(friction=mu)
    low, high = (b.particles for b in sim.model.bodies)
    sim.advance(int(round(SETTLE / dt)))
    x, v = sim.state.numpy()
    settled = float(np.abs(v).max())
    v[high] += [PUSH, 0.0, 0.0]
    sim.state.set(x, v)
    t = SAMPLE * np.arange(1, SAMPLES + 1)
    rel = []
    for _ in t:
        sim.advance(int(round(SAMPLE / dt)))
        v = sim.state.numpy()[1]
        rel.append(v[high, 0].mean() - v[low, 0].mean())
    rel = np.array(rel)
    fit = (t >= FIT[0] - 1e-9) & (t <= FIT[1] + 1e-9)
    deceleration = float("nan") if sim.diverged else -float(np.polyfit(t[fit], rel[fit], 1)[0])
    stats = _contact_stats(sim)
    return {"integrator": integrator, "dt": dt, "mu": mu, "mu_g": mu * G,
            "deceleration": deceleration, "settled_speed": settled,
            "relative_vx": [float(r) for r in rel], "diverged": bool(sim.diverged),
            "unconverged_steps": int(stats.get("unconverged_steps", 0)), "steps": sim.steps}


def cost(integrator: str, dt: float, horizon: float, repeats: int) -> dict:
    """The pile for ``horizon`` [s] with body contact off and on (module doc): median wall times [s],
    their ratio, the deepest overlap [m] and the contact run's solver counters."""
    from ..sim.integrators import names
    from ..sim.scene import load_scene
    from ..sim.simulation import Simulation
    from ..timing import Candidate, time_candidates

    steps = int(round(horizon / dt))
    sims = {on: Simulation(load_scene("pile", [f"solver.body_contact={'true' if on else 'false'}"],
                                      integrator_names=names()), integrator=integrator, dt=dt)
            for on in (False, True)}

    def candidate(sim):
        def setup():
            sim.reset()
            sim.integrator.stats()  # reads and clears the counters of earlier runs

        return Candidate(run=lambda: sim.advance(steps), setup=setup, warmup=lambda: sim.advance(steps))

    times = time_candidates({on: candidate(sim) for on, sim in sims.items()}, repeats)
    sim = sims[True]  # once more, untimed, for its counters
    sim.reset()
    sim.integrator.stats()
    sim.advance(steps)
    stats = _contact_stats(sim)
    return {"integrator": integrator, "dt": dt, "horizon": horizon, "off_s": times[False].median,
            "on_s": times[True].median, "ratio": times[True].median / times[False].median,
            "deepest_overlap_m": stats["body_deepest_overlap_m"],
            "pairs_per_step": stats["body_pairs_in_contact_per_step"],
            "unconverged_steps": int(stats.get("unconverged_steps", 0)), "diverged": bool(sim.diverged)}


def _contact_stats(sim) -> dict:
    """The integrator's counters since the last call and the body contacts' since the start (what
    the run summary shows)."""
    return {**sim.integrator.stats(), **(sim.contacts.stats() if sim.contacts else {})}


def run(quick: bool, progress=None) -> dict:
    """Every slide and cost case; ``progress(done, total, what)`` after each."""
    slides = [(name, mu, dt) for name, dt in SLIDE_RUNS for mu in MUS if not quick or (mu > 0 and name == "fast_mass_spring")]
    costs = COST_RUNS[:1] if quick else COST_RUNS
    total, out, sims = len(slides) + len(costs), {"slide": [], "cost": []}, {}
    for name, mu, dt in slides:
        out["slide"].append(slide(name, mu, dt, sims=sims))
        if progress:
            progress(len(out["slide"]), total, f"slide {name} mu={mu}")
    for name, dt in costs:
        out["cost"].append(cost(name, dt, 2.0 if quick else 4.0, 2 if quick else 3))
        if progress:
            progress(len(out["slide"]) + len(out["cost"]), total, f"pile {name}")
    return out


def markdown(result: dict) -> list[str]:
    """The two tables of CONTACT.md."""
    out = ["## A cube sliding on a cube", "", _section("slide"), "",
           "| solver | dt [s] | mu | deceleration [m/s^2] | mu g [m/s^2] | off by | relative v_x at 0.05 / 0.3 / 0.8 s [m/s] "
           "| unconverged / all steps |", "|---|---:|---:|---:|---:|---:|---|---:|"]
    for r in result["slide"]:
        if r["diverged"]:
            out.append(f"| {r['integrator']} | 1/{1 / r['dt']:.0f} | {r['mu']:g} | diverged | {r['mu_g']:.2f} | | | |")
            continue
        off = "-" if r["mu"] == 0 else f"{r['deceleration'] / r['mu_g'] - 1:+.1%}"
        v = r["relative_vx"]
        out.append(f"| {r['integrator']} | 1/{1 / r['dt']:.0f} | {r['mu']:g} | {r['deceleration']:.2f} | "
                   f"{r['mu_g']:.2f} | {off} | {v[0]:.2f} / {v[5]:.2f} / {v[-1]:.2f} | "
                   f"{r['unconverged_steps']} / {r['steps']} |")
    out += ["", "## What contact costs in the pile", "", _section("cost"), "",
            "| solver | dt [s] | simulated [s] | off [s] | on [s] | on / off | deepest overlap [mm] | pairs per step | unconverged |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in result["cost"]:
        out.append(f"| {r['integrator']} | {r['dt']:.4g} | {r['horizon']:g} | {r['off_s']:.2f} | {r['on_s']:.2f} | "
                   f"**{r['ratio']:.2f}x** | {r['deepest_overlap_m'] * 1e3:.1f} | {r['pairs_per_step']:.0f} | "
                   f"{r['unconverged_steps']} |")
    return out


def _section(name: str) -> str:
    """The module doc's bullet ``name`` as one paragraph (for CONTACT.md)."""
    text = __doc__.split(f"* **{name}**: ", 1)[1].split("\n* ")[0].split("\n\n")[0]
    text = " ".join(text.split()).replace("``", "`")
    return text[0].upper() + text[1:]
