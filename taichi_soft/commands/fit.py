"""``fit``: find spring stiffness, damping, restitution, friction, gravity or mass that reproduce a
recorded motion (a ``run --states`` file or a CSV of marker tracks, named by particle index or by
a point on the rest shape), by Levenberg-Marquardt on forward-mode derivatives
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
    p = sub.add_parser("fit", help="fit material, contact and start parameters to a recorded motion (--states file "
                                   "or marker tracks)")
    add_scene_args(p, integrator=False)
    p.add_argument("--target", required=True,
                   help="the motion to match: a .npz written by `run --states`, or a .csv of marker tracks, one "
                        "row per marker and time, with 5 columns time [s], particle index, x, y, z [m], or 7 "
                        "columns time [s], rx, ry, rz, x, y, z [m]: a marker named by its point on the body's rest "
                        "shape in the world frame (rest = center + R p: the body's lattice without "
                        "initial_stretch, turned by its rotation and placed at its center, as at t = 0), tracked "
                        "as the trilinear interpolation of its lattice cell's 8 particles; one form per file, a "
                        "header line allowed, every time lists the same markers")
    p.add_argument("--params", required=True,
                   help="comma-separated parameters to fit: k_stretch, k_shear, k_bend [N/m], kd_stretch, kd_shear, "
                        "kd_bend [N s/m], restitution, friction, gravity [m/s^2], mass [kg], velocity_x, velocity_y, "
                        "velocity_z (initial [m/s]), spin_x, spin_y, spin_z (initial angular velocity [rad/s])")
    p.add_argument("--window", help="T0:T1, the target's frames from T0 to T1 [s] (default: all)")
    p.add_argument("--max-iters", type=int, default=30, help="Levenberg-Marquardt iterations at most (default: 30)")
    p.add_argument("--result", help="write the JSON result here (default: stdout)")
    p.add_argument("--plot", help="write a PNG here: the loss history, the RMS distance from the target per frame "
                                  "(start and fitted), the most-moving coordinate and marker-pair distance")
    p.set_defaults(func=cmd_fit)


def _window(text: str | None):
    if text is None:
        return None
    try:
        t0, t1 = (float(s) for s in text.split(":"))
    except ValueError:
        raise UserError(f"--window {text!r}: write T0:T1 in seconds, e.g. 0:1.5") from None
    return t0, t1


FORMS = "5 columns time, particle index, x, y, z or 7 columns time, rx, ry, rz, x, y, z"


def read_markers(path: str):
    """Marker tracks from a CSV, an optional header line, one row per marker and time, in one of two
    forms: 5 columns time [s], particle index, x, y, z [m], or 7 columns time [s], rx, ry, rz, x, y,
    z [m] with the marker named by its point (rx, ry, rz) on the rest shape
    (``gradients.rest_point_markers`` says in which frame). Returns (times [frames], markers,
    positions [frames, markers, 3]); markers are sorted particle indices, or sorted rest points as
    (rx, ry, rz) tuples. Every time must list the same markers once each; ``UserError`` (one line)
    otherwise."""
    import csv

    import numpy as np

    where = f"--target {path}"
    try:
        with open(path, newline="") as f:
            rows = [(no, r) for no, r in enumerate(csv.reader(f), 1) if any(c.strip() for c in r)]
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise UserError(f"{where}: cannot read it ({e})") from None
    if rows and not _is_number(rows[0][1][0]):
        rows = rows[1:]  # the header
    if not rows:
        raise UserError(f"{where}: no marker rows ({FORMS})")
    width = len(rows[0][1])
    if width not in (5, 7):
        raise UserError(f"{where}: line {rows[0][0]} has {width} columns, not 5 or 7 ({FORMS})")
    by_rest = width == 7
    what = "rest points" if by_rest else "particles"
    tracks = {}
    for no, row in rows:
        if len(row) != width:
            raise UserError(f"{where}: line {no} has {len(row)} columns, line {rows[0][0]} {width}: one form "
                            f"per file ({FORMS})")
        try:
            values = [float(c) for k, c in enumerate(row) if by_rest or k != 1]
            key = tuple(values[1:4]) if by_rest else int(row[1])
        except ValueError:
            raise UserError(f"{where}: line {no}: not numbers ({FORMS}; a particle index is an integer)") from None
        if not all(np.isfinite(values)) or (not by_rest and key < 0):
            raise UserError(f"{where}: line {no}: a value is not finite or the particle index is negative")
        t, xyz = values[0], tuple(values[-3:])
        frame = tracks.setdefault(t, {})
        if key in frame:
            name = f"rest point ({', '.join(f'{c:g}' for c in key)})" if by_rest else f"particle {key}"
            raise UserError(f"{where}: line {no}: {name} at t = {t:g} s a second time")
        frame[key] = xyz
    times = sorted(tracks)
    markers = sorted(tracks[times[0]])
    for t in times:
        if sorted(tracks[t]) != markers:
            raise UserError(f"{where}: t = {t:g} s lists other {what} than t = {times[0]:g} s; "
                            f"every time must list the same {what}")
    target = np.array([[tracks[t][m] for m in markers] for t in times], dtype=np.float64)
    return np.array(times), markers, target


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


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
    markers = None
    if str(args.target).lower().endswith(".csv"):
        t, markers, target = read_markers(args.target)
    else:
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
    import taichi as ti

    if ti.lang.impl.current_cfg().arch not in (ti.x64, ti.arm64, ti.cuda):
        raise UserError(f"fit needs f64 kernels: --arch cpu or cuda, not {args.arch}")
    from ..sim.simulation import Simulation

    sim = Simulation(scene)
    weights = None
    particles = markers
    if markers is not None and isinstance(markers[0], tuple):
        try:
            particles, weights = gradients.rest_point_markers(sim.model.bodies[0].spec, markers)
        except ValueError as e:
            raise UserError(f"--target: {e}") from None
    elif markers is not None and markers[-1] >= sim.model.n_particles:
        raise UserError(f"--target names particle {markers[-1]}; the scene has {sim.model.n_particles} "
                        f"(0-{sim.model.n_particles - 1})")
    if markers is None and target.shape[1:] != (sim.model.n_particles, 3):
        raise UserError(f"--target has {target.shape[1]} particles, the scene {sim.model.n_particles}")
    problem = tangent.TangentProblem(sim)
    start = problem.values()
    begin = time.perf_counter()

    def progress(it, loss, values):
        shown = ", ".join(f"{p}={values[p]:.6g}" for p in names)
        print(f"fit: iteration {it}/{args.max_iters}: loss {loss:.4g} m^2; {shown}", file=sys.stderr)

    out = gradients.fit(problem, target[keep], [int(s) for s in steps], names, max_iters=args.max_iters,
                        progress=progress, particles=particles, weights=weights)
    out.update(start={p: start[p] for p in names}, wall_seconds=time.perf_counter() - begin,
               frames=int(keep.sum()), particles=sim.model.n_particles, scene=scene.name,
               markers=None if markers is None else [list(m) if weights is not None else m for m in markers])
    text = json.dumps(finite_or_none(out), indent=2)
    written = []
    failures = []
    if result_path:
        failures += write_output("result", result_path, lambda tmp: Path(tmp).write_text(text + "\n"), written)
    else:
        print(text)
    if plot_path:
        frames = [int(s) for s in steps]
        fitted, started = (gradients.observe(problem.trajectory(v, frames), particles, weights)
                           for v in ({**start, **out["values"]}, start))
        failures += write_output("plot", plot_path,
                                 lambda tmp: _plot(tmp, out, t[keep], target[keep], fitted, started), written)
    common.print_outputs(written)
    for line in failures:
        print(f"error: {line}", file=sys.stderr)
    return common.EXIT_OUTPUT if failures else EXIT_OK


def _plot(path, out, t, target, fitted, started):
    """Four panels: the loss history; the RMS distance [m] of the markers (or particles) from the
    target per frame, at the start and fitted; the track of the one coordinate of one marker that
    moves most in the target; and the distance between the two markers whose distance varies most
    in the target (rotation and translation leave it alone: it shows the body's deformation, which
    is what the material sets). The last two: target against start and fitted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ((a, b), (c, d)) = plt.subplots(2, 2, figsize=(11, 8))
    a.semilogy(out["loss_history"], "o-")
    a.set_xlabel("iteration")
    a.set_ylabel("loss [m^2]")
    for x, style, label in ((started, "b:", "start"), (fitted, "r-", "fitted")):
        rms = np.sqrt(np.mean(np.sum((x - target) ** 2, axis=2), axis=1))
        b.semilogy(t, np.where(rms > 0, rms, np.nan), style, label=label)  # a frame matched exactly: no point
    b.set_xlabel("t [s]")
    b.set_ylabel("RMS distance from the target [m]")
    b.legend()
    span = target.max(axis=0) - target.min(axis=0)  # [markers, 3]
    m, axis = np.unravel_index(int(np.argmax(span)), span.shape)
    c.plot(t, target[:, m, axis], "k-", label="target")
    c.plot(t, started[:, m, axis], "b:", label="start")
    c.plot(t, fitted[:, m, axis], "r--", label="fitted")
    c.set_xlabel("t [s]")
    c.set_ylabel(f"marker {m}: {'xyz'[axis]} [m]")
    c.legend()
    some = np.unique(np.linspace(0, target.shape[1] - 1, min(target.shape[1], 16)).astype(int))  # pairs of <= 16
    if len(some) > 1:
        def distances(x):
            return np.linalg.norm(x[:, some, None] - x[:, None, some], axis=3)

        dt_ = distances(target)
        i, j = np.unravel_index(int(np.argmax(dt_.max(axis=0) - dt_.min(axis=0))), dt_.shape[1:])
        for x, style, label in ((target, "k-", "target"), (started, "b:", "start"), (fitted, "r--", "fitted")):
            d.plot(t, distances(x)[:, i, j], style, label=label)
        d.set_ylabel(f"distance, markers {some[i]} and {some[j]} [m]")
        d.legend()
    d.set_xlabel("t [s]")
    fig.tight_layout()
    with open(path, "wb") as f:
        fig.savefig(f, format="png")
    plt.close(fig)
