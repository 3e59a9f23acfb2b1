"""``fit``: find spring stiffness, damping, restitution, friction, gravity or mass that reproduce a
recorded motion (a ``run --states`` file), by Levenberg-Marquardt on forward-mode derivatives
(``sim/tangent.py``: one tangent-linear pass gives the run and its derivatives for every parameter)."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from ..errors import UserError
from ..outfiles import finite_or_none
from . import common
from .common import EXIT_OK, add_scene_args, check_output_path, load_scene_from_args, write_output


def add_parser(sub):
    """The ``fit`` command's arguments on the subparsers ``sub``."""
    p = sub.add_parser("fit", help="fit material and contact parameters to a recorded motion (--states file)")
    add_scene_args(p, integrator=False)
    p.add_argument("--target", required=True, help="the motion to match: a .npz written by `run --states`")
    p.add_argument("--params", required=True,
                   help="comma-separated parameters to fit: k_stretch, k_shear, k_bend [N/m], kd_stretch, kd_shear, "
                        "kd_bend [N s/m], restitution, friction, gravity [m/s^2], mass [kg]")
    p.add_argument("--window", help="T0:T1, the target's frames from T0 to T1 [s] (default: all)")
    p.add_argument("--max-iters", type=int, default=30, help="Levenberg-Marquardt iterations at most (default: 30)")
    p.add_argument("--result", help="write the JSON result here (default: stdout)")
    p.add_argument("--plot", help="write a PNG of the loss history and of target against fitted motion here")
    p.set_defaults(func=cmd_fit)


def _window(text: str | None):
    if text is None:
        return None
    try:
        t0, t1 = (float(s) for s in text.split(":"))
    except ValueError:
        raise UserError(f"--window {text!r}: write T0:T1 in seconds, e.g. 0:1.5") from None
    return t0, t1


def cmd_fit(args) -> int:
    import numpy as np

    from ..sim import gradients, tangent

    names = common.parse_name_list(args.params, "--params", list(gradients.PARAMS), "parameter",
                                   "name each parameter once, comma-separated")
    window = _window(args.window)
    result_path = check_output_path(args.result, "--result", [".json"])
    plot_path = check_output_path(args.plot, "--plot", [".png"])
    if args.max_iters < 1:
        raise UserError(f"--max-iters {args.max_iters}: at least 1")
    try:
        data = np.load(args.target)
        t, target = np.asarray(data["t"], dtype=np.float64), np.asarray(data["x"], dtype=np.float64)
    except (OSError, KeyError, ValueError) as e:
        raise UserError(f"--target {args.target}: not a `run --states` file ({e})") from None
    scene = load_scene_from_args(args)
    if scene.sim["integrator"] != "semi_implicit_euler":
        raise UserError(f"fit covers semi_implicit_euler only; the scene's integrator is {scene.sim['integrator']!r} "
                        "(--set sim.integrator=semi_implicit_euler)")
    if len(scene.data["body"]) != 1:
        raise UserError(f"fit covers scenes with one body; {scene.name} has {len(scene.data['body'])}")
    if scene.data["terrain"]["kind"] not in ("plane", "tilted_plane", "none"):
        raise UserError(f"fit covers the plane, the tilted plane and no terrain, not {scene.data['terrain']['kind']!r}")
    keep = np.ones(len(t), dtype=bool) if window is None else (t >= window[0] - 1e-12) & (t <= window[1] + 1e-12)
    if not keep.any():
        raise UserError(f"--window {args.window}: no frame of the target lies in it (its frames span "
                        f"{t.min() if len(t) else 0:g}-{t.max() if len(t) else 0:g} s)")
    dt = float(scene.sim["dt"])
    steps = np.rint(t[keep] / dt).astype(int)
    if np.abs(steps * dt - t[keep]).max() > 1e-6 * dt + 1e-12 or len(set(steps)) != len(steps):
        raise UserError(f"--target: its frame times are not distinct whole steps of the scene's dt {dt:g} s")
    common.start_taichi(args)
    from ..sim.simulation import Simulation

    sim = Simulation(scene)
    if target.shape[1:] != (sim.model.n_particles, 3):
        raise UserError(f"--target has {target.shape[1]} particles, the scene {sim.model.n_particles}")
    problem = tangent.TangentProblem(sim)
    start = problem.values()
    begin = time.perf_counter()

    def progress(it, loss, values):
        shown = ", ".join(f"{p}={values[p]:.6g}" for p in names)
        print(f"fit: iteration {it}/{args.max_iters}: loss {loss:.4g} m^2; {shown}", file=sys.stderr)

    out = gradients.fit(problem, target[keep], [int(s) for s in steps], names, max_iters=args.max_iters,
                        progress=progress)
    out.update(start={p: start[p] for p in names}, wall_seconds=time.perf_counter() - begin,
               frames=int(keep.sum()), particles=sim.model.n_particles, scene=scene.name)
    text = json.dumps(finite_or_none(out), indent=2)
    written = []
    failures = []
    if result_path:
        failures += write_output("result", result_path, lambda tmp: Path(tmp).write_text(text + "\n"), written)
    else:
        print(text)
    if plot_path:
        fitted = problem.trajectory({**start, **out["values"]}, [int(s) for s in steps])
        failures += write_output("plot", plot_path, lambda tmp: _plot(tmp, out, t[keep], target[keep], fitted), written)
    common.print_outputs(written)
    for line in failures:
        print(f"error: {line}", file=sys.stderr)
    return common.EXIT_OUTPUT if failures else EXIT_OK


def _plot(path, out, t, target, fitted):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.semilogy(out["loss_history"], "o-")
    a.set_xlabel("iteration")
    a.set_ylabel("loss [m^2]")
    b.plot(t, target[:, :, 1].mean(axis=1), "k-", label="target")
    b.plot(t, fitted[:, :, 1].mean(axis=1), "r--", label="fitted")
    b.plot(t, target[:, :, 1].min(axis=1), "k:", label="target, lowest")
    b.plot(t, fitted[:, :, 1].min(axis=1), "r:", label="fitted, lowest")
    b.set_xlabel("t [s]")
    b.set_ylabel("height [m]")
    b.legend()
    fig.tight_layout()
    with open(path, "wb") as f:
        fig.savefig(f, format="png")
    plt.close(fig)
