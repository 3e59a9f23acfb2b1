"""Issue 22: first bounce apex of a stiff cube dropped flat, implicit step, against the terrain skin.

The flat case of ``bench precision`` (4^3 cube, edge 2 m, bottom 2 m above the plane) at stiffness
x1000 with ``implicit_euler`` at 1/30 ... 1/960 s, with the default contact epsilon (1 cm) and with
a negligible one (1e-6 m): the centre of mass's first apex above the plane [m] (rest 1.0 m).
usage (from the repository root): .venv/bin/python scripts/bench/skin_bounce.py [INTEGRATOR]  (~1 min)"""
import os
import sys

sys.path.insert(0, os.getcwd())
from taichi_soft import runtime  # noqa: E402

runtime.init("cpu", "f64")
from taichi_soft.bench import precision as P  # noqa: E402

name = sys.argv[1] if len(sys.argv) > 1 else "implicit_euler"
scene, sets, _ = P.case_runs("flat", False)[0]
print("| contact.epsilon | " + " | ".join(f"1/{m} s" for m in (30, 120, 240, 480, 960)) + " |")
print("|---|" + "---:|" * 5)
for eps in (0.01, 1e-6):
    sim = P.build(scene, sets + [f"contact.epsilon={eps}"], name)
    P.set_stiffness(sim, 1000.0, sim.model.group_k.to_numpy().copy())
    apex = [P.summary(P.trajectory(sim, 1.0 / m, 1.5))["apex"] for m in (30, 120, 240, 480, 960)]
    print(f"| {eps:g} | " + " | ".join(f"{a:.3f}" for a in apex) + " |", flush=True)
