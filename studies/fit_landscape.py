"""The teaching experiment of docs/teaching.md ("Fit the stiffness back"): record a run, perturb the
stretch stiffness 2x, fit it back, and plot the loss against the stiffness beside the fit.

Two runs of a 6^3 cube, 2 s, semi-implicit Euler: ``free_float`` (free vibration, no contact; dampers
2 N s/m) and
``plane`` (dropped on a corner, it bounces). For each, the loss (mean squared distance to the
recorded run over frames and particles) on a grid of stretch stiffness, and the iterates of
Levenberg-Marquardt started at 2x the truth. Writes docs/img/teach-10-fit-landscape.png and prints
the fitted values.

    PYTHONPATH=. .venv/bin/python studies/fit_landscape.py
"""
import sys
from pathlib import Path

import numpy as np

from taichi_soft import runtime

runtime.init("cpu", "f64")

from taichi_soft.sim import Simulation, gradients, tangent  # noqa: E402
from taichi_soft.sim.scene import load_scene  # noqa: E402
from taichi_soft.sim.simulation import frame_steps  # noqa: E402

OUT = Path(__file__).resolve().parent.parent / "docs" / "img" / "teach-10-fit-landscape.png"
DURATION = 2.0


# free_float's default dampers (60 N s/m) stop its vibration within 0.2 s; lighter ones let it ring
LIGHT_DAMPERS = [f"body.0.{kind}.damping=2" for kind in ("stretch", "shear", "bend")]


def experiment(scene_name):
    extra = LIGHT_DAMPERS if scene_name == "free_float" else []
    scene = load_scene(scene_name, ["sim.integrator=semi_implicit_euler", "body.0.n=6", f"sim.duration={DURATION}",
                                    *extra])
    sim = Simulation(scene)
    problem = tangent.TangentProblem(sim)
    truth = problem.values()
    steps = frame_steps(int(round(DURATION / sim.dt)), 30, sim.dt)
    target = problem.trajectory(truth, steps)

    def loss(k):
        x = problem.trajectory(dict(truth, k_stretch=k), steps)
        return float(((x - target) ** 2).sum(axis=-1).mean())

    grid = truth["k_stretch"] * np.geomspace(0.25, 4.0, 61)
    landscape = [loss(k) for k in grid]
    path = [2 * truth["k_stretch"]]
    out = gradients.fit(problem, target, steps, ["k_stretch"], start=dict(truth, k_stretch=path[0]),
                        progress=lambda it, lo, vals: path.append(vals["k_stretch"]))
    # the motion panel at 200 frames/s: 30 frames/s alias the cube's ringing (its period is ~0.07 s)
    fine = frame_steps(int(round(DURATION / sim.dt)), 200, sim.dt)
    fitted = problem.trajectory(dict(truth, k_stretch=out["values"]["k_stretch"]), fine)
    start = problem.trajectory(dict(truth, k_stretch=path[0]), fine)
    recorded = problem.trajectory(truth, fine)
    t = np.asarray(fine) * sim.dt
    print(f"{scene_name}: truth {truth['k_stretch']:g} N/m, start {path[0]:g}, fitted {out['values']['k_stretch']:.6g} "
          f"after {len(path) - 1} iterations, loss {out['loss']:.3g} m^2")
    return dict(name=scene_name, truth=truth["k_stretch"], grid=grid, landscape=landscape, path=path,
                path_loss=[loss(k) for k in path], t=t, target=recorded, fitted=fitted, start=start)


def plot(runs):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    for row, run in zip(axes, runs):
        a, b = row
        # the loss is 0 at the truth (a grid point): drawn at 1e-16
        a.loglog(run["grid"], np.maximum(run["landscape"], 1e-16), "k-", lw=1, label="loss")
        a.loglog(run["path"], np.maximum(run["path_loss"], 1e-16), "ro--", ms=4, label="fit's iterates")
        a.axvline(run["truth"], color="g", lw=0.8, label="truth")
        a.set_xticks([500, 1000, 2000, 4000, 8000])
        a.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        a.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        a.set_xlabel("stretch stiffness k [N/m]")
        a.set_ylabel("loss [m^2]")
        a.set_title(f"{run['name']}: loss against stiffness")
        a.legend(fontsize=8)
        # a motion a class can read: the length of the body's diagonal (free_float: it spins, so
        # no fixed axis shows the stretch) or its lowest point (plane)
        if run["name"] == "plane":
            what, f = "lowest point y [m]", (lambda x: x[:, :, 1].min(axis=1))
        else:
            what, f = "corner-to-corner distance [m]", (lambda x: np.linalg.norm(x[:, 0] - x[:, -1], axis=1))
            b.set_xlim(0, 1)
        b.plot(run["t"], f(run["target"]), "k-", label="recorded (truth)")
        b.plot(run["t"], f(run["start"]), "b:", label="start, 2x stiffer")
        b.plot(run["t"], f(run["fitted"]), "r--", label="fitted")
        b.set_xlabel("t [s]")
        b.set_ylabel(what)
        b.set_title(f"{run['name']}: motion")
        b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT, dpi=90)
    plt.close(fig)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    plot([experiment(name) for name in (sys.argv[1:] or ["free_float", "plane"])])
