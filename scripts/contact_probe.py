"""Probe of the implicit solvers' contact iterations (issue 22 item 5): the five drops of the
default cube (n = 10, the bench ensemble's rotations), a push and a rest on a shallow slope, at a
stiffness scale and step, for given solver options. Prints one JSON line per run.

    TAICHI_SOFT_OPTIMIZE=0 python scripts/contact_probe.py fast_mass_spring \
        --set friction_velocity=0.01 --scale 10 --dt 0.0333333 --runs drops,push,rest
"""
import argparse
import json
import math
import sys
import time

import numpy as np

sys.path.insert(0, ".")
import taichi as ti  # noqa: E402

from taichi_soft.bench.plausibility import slide_distance  # noqa: E402
from taichi_soft.bench.precision import ENSEMBLE  # noqa: E402
from taichi_soft.sim.integrators import names  # noqa: E402
from taichi_soft.sim.scene import load_scene  # noqa: E402
from taichi_soft.sim.simulation import Simulation  # noqa: E402

TAN = 0.2  # rest run: slope tan(theta) (mu = 0.3 holds it)


def value(v):
    try:
        return json.loads(v)
    except ValueError:
        return v


def runs(which):
    out = []
    if "drops" in which:
        for k, (a, d) in enumerate(ENSEMBLE):
            out.append((f"drop{k}", "plane", [f"body.0.rotation={{axis = [{a[0]}, {a[1]}, {a[2]}], degrees = {d}}}"], 3.0))
    if "push" in which:
        out.append(("push", "plane", ["body.0.center=[0, 1.0, 0]", "body.0.rotation.degrees=0",
                                      "body.0.velocity=[3.0, 0, 0]"], 2.0))
    if "rest" in which:
        th = math.atan(TAN)
        c = 2.0 + 0.01
        out.append(("rest", "tilted_plane", [f"terrain.normal=[{math.sin(th)}, {math.cos(th)}, 0]",
                                             f"body.0.center=[{c * math.sin(th)}, {c * math.cos(th)}, 0]",
                                             f"body.0.rotation={{axis = [0, 0, 1], degrees = {-math.degrees(th)}}}"], 4.0))
    return out


def one(name, scene, sets, t_end, solver, opts, scale, dt):
    sim = Simulation(load_scene(scene, sets, integrator_names=names()), solver, dt, options=opts)
    base = sim.model.group_k.to_numpy().copy()
    sim.model.set_group_stiffness(base[: sim.model.n_groups] * scale)
    sim.set_dt(dt)
    sim.reset()
    integ = sim.integrator
    integ.stats()
    it_key = "local_global_iterations_per_step" if solver == "fast_mass_spring" else "newton_iterations_per_step"
    com = [sim.measure()["center_of_mass"]]
    steps = []
    first_contact = None
    for k in range(int(round(t_end / dt))):
        ti.sync()
        t0 = time.perf_counter()
        sim.advance(1)
        ti.sync()
        wall = time.perf_counter() - t0
        st = integ.stats()
        hist = integ.residual_history()
        contact = float(integ.sc.n_active[None]) > 0
        if contact and first_contact is None:
            first_contact = k
        its = st[it_key]
        red = (hist[-1] / hist[0]) ** (1.0 / its) if its > 0 and hist[0] > 0 and hist[-1] > 0 else float("nan")
        steps.append({"its": its, "contact": contact, "wall": wall, "unconv": st["unconverged_steps"],
                      "clamp": st["energy_clamped_steps"], "failed": st["failed_solve_steps"],
                      "res0": hist[0] if hist else float("nan"), "res": hist[-1] if hist else float("nan"), "red": red})
        com.append(sim.measure()["center_of_mass"])
        if sim.diverged:
            break
    com = np.asarray(com)
    c = [s for s in steps if s["contact"]]
    land = [s for s in steps[first_contact:first_contact + 13]] if first_contact is not None else []
    red_land = [s["red"] for s in land if s["its"] > 0 and math.isfinite(s["red"])]
    out = {"run": name, "solver": solver, "opts": opts, "scale": scale, "dt": dt, "steps": len(steps),
           "diverged": sim.diverged, "its_all": np.mean([s["its"] for s in steps]),
           "its_contact": np.mean([s["its"] for s in c]) if c else 0.0, "contact_steps": len(c),
           "its_land13": np.mean([s["its"] for s in land]) if land else 0.0,
           "red_land13": float(np.exp(np.mean(np.log(red_land)))) if red_land else float("nan"),
           "res_land13": float(np.mean([s["res"] for s in land])) if land else float("nan"),
           "ms_contact": 1e3 * float(np.median([s["wall"] for s in c[1:]])) if len(c) > 1 else float("nan"),
           "ms_land13": 1e3 * float(np.median([s["wall"] for s in land])) if land else float("nan"),
           "wall_total": float(sum(s["wall"] for s in steps[1:])),  # step 0 compiles
           "res_mean": float(np.mean([s["res"] for s in steps if math.isfinite(s["res"])] or [float("nan")])),
           "unconverged": sum(s["unconv"] for s in steps), "clamped": sum(s["clamp"] for s in steps),
           "failed": sum(s["failed"] for s in steps), "com": com.tolist()}
    if name == "push":
        times = dt * np.arange(len(com))
        out["slide"] = slide_distance({"diverged": sim.diverged, "com": com, "times": times})
        g, mu = 9.8, float(sim.terrain.friction[None])
        out["slide_expected"] = 9.0 / (2 * mu * g)
    if name == "rest":
        th = math.atan(TAN)
        tdir = np.array([math.cos(th), -math.sin(th), 0.0])  # downhill along the slope
        d = (com - com[0]) @ tdir
        out["creep_4s"] = float(d[-1])
        out["creep_last2s"] = float(d[-1] - d[len(d) // 2])
    return out


def main():
    p = argparse.ArgumentParser()
    p.add_argument("solver")
    p.add_argument("--set", action="append", default=[])
    p.add_argument("--scale", type=float, default=10.0)
    p.add_argument("--dt", type=float, default=1.0 / 30.0)
    p.add_argument("--runs", default="drops,push,rest")
    a = p.parse_args()
    from taichi_soft import runtime
    runtime.init("cpu", "f64")
    opts = {k: value(v) for k, v in (s.split("=", 1) for s in a.set)}
    for name, scene, sets, t_end in runs(a.runs.split(",")):
        print(json.dumps(one(name, scene, sets, t_end, a.solver, opts, a.scale, a.dt)), flush=True)


if __name__ == "__main__":
    main()
