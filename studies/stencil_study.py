"""Stencil force pass against the gather's padded rows (both with fast math): steps/s and peak memory.

    PYTHONPATH=. .venv/bin/python studies/stencil_study.py speed f64   # one process per precision
    PYTHONPATH=. .venv/bin/python studies/stencil_study.py mesh f64    # the torus (presence mask)
    PYTHONPATH=. .venv/bin/python studies/stencil_study.py memory      # fresh CLI runs, VmHWM

Speed: semi-implicit Euler on the plane scene's cube (edge 4 m), dt = 1 ms, fast math on (the
command line's default), all threads, parallel launches; both passes built in one process, warmed
up, then timed in turn (taichi_soft.timing: interleaved, ti.sync(), medians). ``mesh``: the same
on the torus scene's mesh body at n = 40 and 80 lattice points along its longest side. Results:
docs/benchmarks/STENCIL.md.
"""
import json
import sys

from taichi_soft import runtime


def speed(precision: str, scene: str = "plane", sizes=((40, 20), (80, 4))):
    runtime.init("cpu", precision, fast_math=True)
    from taichi_soft.sim.integrators import names
    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import Simulation
    from taichi_soft.timing import Candidate, time_candidates

    out = {}
    for n, steps in sizes:
        cands, sims = {}, {}
        for forces in ("gather", "stencil"):
            sim = Simulation(load_scene(scene, [f"body.0.n={n}"], integrator_names=names()),
                             integrator="semi_implicit_euler", options={"forces": forces})
            sims[forces] = sim
            cands[forces] = Candidate(run=lambda s=sim: s.advance(steps), warmup=lambda s=sim: s.advance(steps))
        res = time_candidates(cands, 9)
        for forces, t in res.items():
            out[f"n{n} {precision} {sims[forces].integrator.forces.strategy}"] = steps / t.median
        out[f"n{n} particles"] = sims["stencil"].model.n_particles
        print(json.dumps(out), flush=True)
        del sims, cands


def memory():
    import subprocess
    for precision in ("f64", "f32"):
        for n in (40, 60, 80):
            for forces in ("gather", "stencil"):
                code = ("import sys; from taichi_soft.peak_run import peak_of_run; "
                        f"print(peak_of_run(['run','--scene','plane','--precision','{precision}','--dt','0.001',"
                        f"'--duration','0.001','--set','body.0.n={n}','--set','solver.forces={forces}'], 'cpu'))")
                r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
                print(precision, n, forces, r.stdout.strip()[-200:], r.stderr.strip()[-300:], flush=True)


if __name__ == "__main__":
    if sys.argv[1] == "speed":
        speed(sys.argv[2])
    elif sys.argv[1] == "mesh":
        speed(sys.argv[2], "torus", ((40, 40), (80, 8)))
    else:
        memory()
