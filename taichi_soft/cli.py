"""Command line: ``python main.py [run|list|...]``.

Exit status: 0 success, 2 bad input (one line on stderr, nothing overwritten), 3 the run
diverged (summary and states so far are still written).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

from .errors import UserError

EXIT_OK, EXIT_BAD_INPUT, EXIT_DIVERGED = 0, 2, 3


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error in one line and exits 2."""

    def error(self, message):
        raise UserError(f"{self.prog}: {message} (see --help)")


# -- output files --------------------------------------------------------------------------
def check_output_path(path: str | None, flag: str, suffixes=None) -> Path | None:
    """Fail early (before any simulation) if ``path`` cannot be written. Creates missing parents."""
    if path is None:
        return None
    p = Path(path)
    if suffixes and p.suffix.lower() not in suffixes:
        raise UserError(f"{flag} {path}: expected a file ending in {' or '.join(suffixes)}")
    if p.is_dir():
        raise UserError(f"{flag} {path}: is a directory, expected a file path")
    parent = p.parent if str(p.parent) else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"{flag} {path}: cannot create directory {parent}: {e.strerror}") from None
    if not os.access(parent, os.W_OK):
        raise UserError(f"{flag} {path}: directory {parent} is not writable")
    if p.exists() and not os.access(p, os.W_OK):
        raise UserError(f"{flag} {path}: file exists and is not writable")
    return p


def write_atomic(path: Path, write) -> None:
    """Write through a temporary file in the same directory, then rename over ``path``.

    A crash mid-write never leaves a half-written file where the user's old one was.
    """
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def finite_or_none(obj):
    """JSON has no NaN/inf: replace them (in nested dicts/lists) by null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    return obj


# -- commands --------------------------------------------------------------------------------
def add_scene_args(p: argparse.ArgumentParser, integrator_default_help="the scene's"):
    from .runtime import ARCHS, PRECISIONS

    p.add_argument("--scene", default="plane", help="scene name in scenes/ or a path to a .toml file (default: plane)")
    p.add_argument("--integrator", help=f"integrator name (default: {integrator_default_help} sim.integrator); see `list`")
    p.add_argument("--dt", type=_float_arg("--dt"), help="time step [s] (default: the scene's sim.dt)")
    p.add_argument("--duration", type=_float_arg("--duration"), help="simulated time [s] (default: the scene's sim.duration)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene key by dotted path, e.g. body.0.stretch.k=5000 (repeatable)")
    p.add_argument("--arch", default="cpu", choices=None, help=f"backend: {', '.join(ARCHS)} (default: cpu)")
    p.add_argument("--precision", default="f64", help=f"float precision: {', '.join(PRECISIONS)} (default: f64)")


def _float_arg(flag):
    def parse(text):
        try:
            return float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} {text!r} is not a number") from None
    return parse


def load_scene_from_args(args):
    """Scene from --scene and --set, with --integrator/--dt/--duration applied on top."""
    from .integrators import names
    from .scene import load_scene

    overrides = list(args.set)
    for flag, key in (("integrator", "sim.integrator"), ("dt", "sim.dt"), ("duration", "sim.duration")):
        value = getattr(args, flag, None)
        if value is not None:
            overrides.append(f"{key}={json.dumps(value) if isinstance(value, str) else repr(value)}")
    return load_scene(args.scene, overrides, integrator_names=names())


def start_taichi(args):
    from . import runtime

    return runtime.init(args.arch, args.precision)


def cmd_list(args) -> int:
    from . import runtime
    from .integrators import REGISTRY
    from .scene import SCENES_DIR, scene_names

    print(f"scenes (in {SCENES_DIR}):")
    for name in scene_names():
        print(f"  {name}")
    print("integrators:")
    for name, cls in REGISTRY.items():
        print(f"  {name:22s} order {cls.order}, {cls.description}")
    print("backends (--arch): " + ", ".join(runtime.ARCHS) + f"; available here: {', '.join(runtime.available_archs())}")
    print("precisions (--precision): " + ", ".join(runtime.PRECISIONS))
    return EXIT_OK


def cmd_run(args) -> int:
    import numpy as np

    from .progress import Progress
    from .simulation import Simulation, states_arrays

    scene = load_scene_from_args(args)
    summary_path = check_output_path(args.summary, "--summary", [".json"])
    states_path = check_output_path(args.states, "--states", [".npz"])
    start_taichi(args)
    sim = Simulation(scene)
    duration = scene.sim["duration"]
    fps = scene.data["render"]["fps"]
    bar = Progress(int(round(duration / sim.dt)), f"{scene.name}/{sim.integrator_name}")
    result = sim.run(duration, fps, record=states_path is not None,
                     progress=lambda done, total, s: bar.update(done, f"t={s.time:6.3f}s"))
    bar.close()
    summary = sim.summary(result)
    if summary_path:
        text = json.dumps(finite_or_none(summary), indent=2)
        write_atomic(summary_path, lambda tmp: Path(tmp).write_text(text + "\n"))
    if states_path:
        arrays = states_arrays(result.frames, sim.model.real)
        write_atomic(states_path, lambda tmp: np.savez(open(tmp, "wb"), **arrays))
    if result.diverged:
        print(f"diverged at t = {result.diverged_at:.4f} s (step {result.diverged_step}) with {sim.integrator_name} "
              f"at dt = {sim.dt:g} s; try --dt {sim.suggest_dt():g} or a more stable integrator", file=sys.stderr)
        return EXIT_DIVERGED
    f = summary["final"]
    com = ", ".join(f"{c:.3f}" for c in f["center_of_mass"])
    print(f"{scene.name}/{sim.integrator_name}: {result.steps} steps of {sim.dt:g} s = {result.sim_time:.3f} s simulated "
          f"in {result.wall_seconds:.2f} s wall ({summary['steps_per_second']:.0f} steps/s); "
          f"final centre of mass ({com}), kinetic energy {f['kinetic_energy']:.3g} J")
    for label, path in (("summary", summary_path), ("states", states_path)):
        if path:
            print(f"{label}: {path}")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="main.py", description="taichi-soft: mass-spring soft bodies on Taichi")
    sub = parser.add_subparsers(dest="command", parser_class=_Parser)
    p_run = sub.add_parser("run", help="simulate a scene; write a summary, states (and video)")
    add_scene_args(p_run)
    p_run.add_argument("--summary", help="write a JSON run summary here")
    p_run.add_argument("--states", help="write sampled states (t, x, v) to this .npz")
    p_run.set_defaults(func=cmd_run)
    p_list = sub.add_parser("list", help="list scenes, integrators and backends")
    p_list.set_defaults(func=cmd_list)
    return parser


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if args.command is None:
            return main_job()
        return args.func(args)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


def main_job() -> int:
    """``python main.py`` with no arguments: the default scene, summary written under out/."""
    return main(["run", "--scene", "plane", "--summary", "out/plane-summary.json"])
