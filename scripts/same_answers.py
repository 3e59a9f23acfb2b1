"""Fingerprints of a fixed set of runs, to show a refactor changes no answer, bit for bit.

Every registered integrator on every terrain (a 5^3 cube, 2 s from the scene's own drop, landing
included, at a step each method is stable at), the two multi-body scenes (three_cubes, pile:
explicit and implicit body contact), the implicit solvers' parallel driver on two terrains, and
their BDF2 scheme (``solver.scheme = bdf2``, serial and parallel, on two terrains), each run
through ``Simulation`` in f64 with fast math off. Prints one line per run,
``scene integrator [bdf2] [serial|parallel] dt sha256(x, v)``, then one digest of all lines.

    .venv/bin/python scripts/same_answers.py > before.txt    # at the old commit
    .venv/bin/python scripts/same_answers.py > after.txt     # at the new one
    diff before.txt after.txt                                 # no output: the same answers

Compare runs made with the same TAICHI_SOFT_OPTIMIZE setting (Taichi's IR passes may reorder
arithmetic). Takes about 5 minutes on the 2-core VM with TAICHI_SOFT_OPTIMIZE=0.

``--stats`` adds to each line ``stats`` and a hash of the integrator's ``stats()`` after the run
(iterations, CG iterations, refreezes, clamped and failed steps, pair counters...), for a change
that must also leave the solvers' work unchanged; the default lines stay as they were.
"""
import hashlib
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from taichi_soft import runtime  # noqa: E402

runtime.init("cpu", "f64")

from taichi_soft.sim.integrators import REGISTRY, names  # noqa: E402
from taichi_soft.sim.scene import load_scene  # noqa: E402
from taichi_soft.sim.simulation import Simulation  # noqa: E402

TERRAINS = ("plane", "tilted_plane", "sphere", "bowl")
SMALL = ["body.0.n=5"]
DURATION = 2.0  # [s]: the single bodies land by about 1.4 s


STATS = "--stats" in sys.argv[1:]


def fingerprint(scene: str, integrator: str, dt: float, sets=()) -> str:
    sim = Simulation(load_scene(scene, list(sets), integrator_names=names()), integrator=integrator, dt=dt)
    sim.advance(int(round(DURATION / dt)))
    x, v = sim.state.numpy()
    out = hashlib.sha256(x.tobytes() + v.tobytes()).hexdigest()[:16]
    if STATS:
        stats = json.dumps(sim.integrator.stats(), sort_keys=True, default=str)
        out += " stats " + hashlib.sha256(stats.encode()).hexdigest()[:16]
    return out


def main():
    lines = []
    for terrain in TERRAINS:
        for name, cls in REGISTRY.items():
            dt = 1 / 60 if cls.implicit else 5e-4
            lines.append(f"{terrain} {name} {dt:.6g} {fingerprint(terrain, name, dt, SMALL)}")
            print(lines[-1], flush=True)
    for scene in ("three_cubes", "pile"):
        for name, dt in (("semi_implicit_euler", 5e-4), ("implicit_euler", 1 / 60), ("fast_mass_spring", 1 / 60)):
            lines.append(f"{scene} {name} {dt:.6g} {fingerprint(scene, name, dt)}")
            print(lines[-1], flush=True)
    # The implicit solvers' parallel driver (one launch per phase; the 5^3 cube runs serially by
    # default). Not pile: its pair terms are summed by parallel atomic adds, whose order varies, so
    # three parallel runs of pile with fast_mass_spring gave three fingerprints (2026-12-02).
    for scene, sets in (("plane", SMALL), ("bowl", SMALL)):
        for name in ("implicit_euler", "fast_mass_spring"):
            run = fingerprint(scene, name, 1 / 60, list(sets) + ["solver.mode=parallel"])
            lines.append(f"{scene} {name} parallel {1 / 60:.6g} {run}")
            print(lines[-1], flush=True)
    # BDF2 (its flight steps; contact steps are backward Euler), both drivers.
    for scene in ("plane", "sphere"):
        for name in ("implicit_euler", "fast_mass_spring"):
            for mode in ("serial", "parallel"):
                run = fingerprint(scene, name, 1 / 60, SMALL + ["solver.scheme=bdf2", f"solver.mode={mode}"])
                lines.append(f"{scene} {name} bdf2 {mode} {1 / 60:.6g} {run}")
                print(lines[-1], flush=True)
    print("all", hashlib.sha256("\n".join(lines).encode()).hexdigest()[:16])


if __name__ == "__main__":
    main()
