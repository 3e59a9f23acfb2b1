"""Cost of a gradient against the engine's forward run (docs/gradients.md, "Cost and memory").

Per cube: the engine's semi-implicit Euler run, the tangent-linear stepper's real pass and its
passes with P = 1, 2, 4 parameters (one pass gives all P columns), and for the small cubes the
complex-step reference's one-parameter pass. Interleaved, medians after a warm-up; the load
average is printed beside each line. ``--fit`` times the command line's fit of a 10^3 cube over
2 s instead (stiffness and damping of the stretch springs from 2x off, free vibration).

    PYTHONPATH=. .venv/bin/python studies/gradient_cost.py [--fit]
"""
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def load():
    return Path("/proc/loadavg").read_text().split()[0]


def fit_study():
    """`run --states` a 10^3 cube over 2 s, then `fit` it from 2x off; wall of the fit process."""
    scene = ["--scene", "free_float", "--set", "sim.integrator=semi_implicit_euler", "--set", "body.0.n=10",
             "--duration", "2"]
    env = dict(os.environ, PYTHONPATH=".")
    with tempfile.TemporaryDirectory() as tmp:
        target, result = Path(tmp) / "t.npz", Path(tmp) / "r.json"
        subprocess.run([sys.executable, "main.py", "run", *scene, "--states", str(target)], check=True, env=env,
                       capture_output=True)
        begin, before = time.perf_counter(), load()
        done = subprocess.run([sys.executable, "main.py", "fit", *scene, "--set", "body.0.stretch.k=4000",
                               "--set", "body.0.stretch.damping=30", "--target", str(target),
                               "--params", "k_stretch,kd_stretch", "--result", str(result)],
                              env=env, capture_output=True, text=True)
        wall = time.perf_counter() - begin
        if done.returncode != 0:
            raise SystemExit(done.stderr)
        out = json.loads(result.read_text())
    print(f"fit n=10 (1000 particles) over 2 s, k_stretch and kd_stretch from 2x off: process wall {wall:.1f} s, "
          f"fit {out['wall_seconds']:.1f} s, {out['gradient_evaluations']} gradients, {out['forward_runs']} runs, "
          f"values {out['values']} (load {before} -> {load()})")


def pass_study():
    from taichi_soft import runtime

    runtime.init("cpu", "f64")
    from taichi_soft.sim import Simulation, gradients, scene_from_dict, tangent
    from taichi_soft.sim.simulation import frame_steps

    def make(n):
        return Simulation(scene_from_dict({
            "sim": {"integrator": "semi_implicit_euler", "dt": 1e-3, "gravity": [0, -9.8, 0]},
            "body": [{"n": n, "size": 1.0, "particle_mass": 0.5, "center": [0, 0.9, 0],
                      "stretch": {"k": 500.0, "damping": 2.0}, "shear": {"k": 300.0, "damping": 1.0},
                      "bend": {"k": 200.0, "damping": 1.0}}],
            "terrain": {"kind": "plane", "point": [0, 0, 0], "normal": [0, 1, 0]},
            "contact": {"restitution": 0.5, "friction": 0.3}}))

    def timed(fn):
        t = time.perf_counter()
        fn()
        return time.perf_counter() - t

    for n, dur in ((3, 1.0), (5, 1.0), (10, 1.0)):
        sim = make(n)
        steps = frame_steps(int(round(dur / 1e-3)), 30, 1e-3)
        ref, fast = gradients.Problem(sim), tangent.TangentProblem(sim)
        vals = ref.values()
        runs = {"engine": lambda: (sim.reset(), sim.run(dur, 30, record=True)),
                "real": lambda: fast.trajectory(vals, steps)}
        for p in (1, 2, 4):
            runs[f"P={p}"] = lambda p=p: fast.jacobian(vals, list(gradients.PARAMS[:p]), steps)
        if n <= 5:
            runs["complex"] = lambda: ref.trajectory(vals, steps, seed="k_stretch")
        times = {k: [] for k in runs}
        before = load()
        for _ in range(4):  # interleaved; the first of each is the warm-up (and the compile)
            for k, fn in runs.items():
                times[k].append(timed(fn))
        med = {k: statistics.median(v[1:]) for k, v in times.items()}
        eng = med["engine"]
        shown = ", ".join(f"{k} {v * 1e3:.1f} ms ({v / eng:.2f})" for k, v in med.items())
        print(f"n={n} particles={sim.model.n_particles} springs={sim.model.n_springs} run {dur} s: {shown} "
              f"[in engine runs] (load {before} -> {load()})")


if __name__ == "__main__":
    fit_study() if "--fit" in sys.argv[1:] else pass_study()
