"""Command line: ``python main.py [run|list|...]``.

Exit status: 0 success, 2 bad input (one line on stderr, nothing overwritten), 3 the run
diverged (summary and states so far are still written), 4 an output could not be written (one
line per output; each keeps its old file), 5 a sweep's task failed every attempt (the others' outputs are
still written), 130 / 143 / 129 interrupted by SIGINT / SIGTERM / SIGHUP (nothing half-written is
left; a sweep keeps what finished).
"""
from __future__ import annotations

import argparse
import signal
import sys

from .commands.bench import cmd_bench
from .commands.common import (DEFAULT_OUT, EXIT_BAD_INPUT, EXIT_DIVERGED, EXIT_OK, EXIT_OUTPUT,  # noqa: F401
                              EXIT_REPLAY_DIFFERS, EXIT_TASKS_FAILED, EXIT_UNRELIABLE, Choices, float_arg, Parser,
                              resolution_arg, add_fast_math_arg, add_render_args, add_scene_args, add_task_args)
from .commands.compare import cmd_compare
from .commands.demo import cmd_demo
from .commands.gallery import cmd_gallery
from .commands.listing import cmd_list
from .commands.run import cmd_run
from .errors import OutputError, Terminated, UserError

# The main job (`python main.py`): the assignment's cube dropped on the plane.
DEFAULT_SCENE, DEFAULT_INTEGRATOR = "plane", "rk4"
DEFAULT_COMPARE = "explicit_euler,semi_implicit_euler,midpoint,rk4"


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="main.py", description="taichi-soft: mass-spring soft bodies on Taichi")
    sub = parser.add_subparsers(dest="command", parser_class=Parser)
    p_run = sub.add_parser("run", help="simulate a scene; write a summary, states (and video)")
    add_scene_args(p_run)
    p_run.add_argument("--summary", help="write a JSON run summary here")
    p_run.add_argument("--states", help="write sampled states (t, x, v) to this .npz")
    p_run.add_argument("--dry-run", action="store_true",
                       help="print what would be simulated and written and the memory estimate, then exit")
    add_render_args(p_run)
    p_run.set_defaults(func=cmd_run)
    p_cmp = sub.add_parser("compare", help="run one scene with several integrators at the same dt; write a mosaic video")
    add_scene_args(p_cmp, integrator=False)
    p_cmp.add_argument("--integrators", default=DEFAULT_COMPARE,
                       help=f"comma-separated integrator names, one tile each (default: {DEFAULT_COMPARE})")
    add_render_args(p_cmp, mesh_export=False, pipeline=False)
    p_cmp.set_defaults(func=cmd_compare)
    p_demo = sub.add_parser("demo", help="open the interactive classroom window (needs a display and Vulkan)")
    add_scene_args(p_demo)
    next(a for a in p_demo._actions if a.dest == "duration").help = \
        "stop the simulation at this simulated time [s] (R restarts; default: run on)"
    p_demo.add_argument("--resolution", type=resolution_arg, metavar="WxH", default=[1280, 800],
                        help="window size in pixels (default: 1280x800)")
    p_demo.add_argument("--paused", action="store_true", help="start paused: Space plays (R also resets paused)")
    p_demo.add_argument("--record", metavar="SESSION.json",
                        help="save every input (keys, buttons, sliders, mouse grabs, pokes, pins) with its time to "
                             "this file when the window closes, for --replay")
    p_demo.add_argument("--replay", metavar="SESSION.json",
                        help="play a recorded session back without a window into a video (its scene, settings, "
                             "backend and precision come from the file; exit 7 if it ends elsewhere than the "
                             "live session did)")
    p_demo.add_argument("--video", metavar="PATH",
                        help="with --replay: the video to write, .mp4 or .gif (default: out/demo-<scene>-replay-<date>.mp4)")
    p_demo.add_argument("--frames", type=int, metavar="N", help="draw N frames, then close the window (for scripts)")
    p_demo.add_argument("--screenshot", metavar="PATH.png", help="with --frames: save the last frame to this PNG")
    p_demo.set_defaults(func=cmd_demo)
    p_bench = sub.add_parser("bench", help="benchmarks: work-precision, stability, kernel speed, full report")
    p_bench.add_argument("study", choices=Choices(["accuracy", "precision", "stability", "speed", "memory", "report", "mesh"],
                                                   hidden=["speed-worker"]),
                         help="what to measure; precision: work-precision at equal error (issue 22); report runs accuracy, "
                              "precision, stability, speed and memory and writes REPORT.md; mesh: the mesh-body "
                              "goals (build time, frame cost), MESH.md")
    p_bench.add_argument("--quick", action="store_true", help="tiny sizes: a few minutes on 2 cores (what CI runs)")
    p_bench.add_argument("--out", help="output folder (default docs/benchmarks, or out/benchmarks-quick with --quick)")
    add_task_args(p_bench)
    p_bench.add_argument("--arch", default="cpu", help=argparse.SUPPRESS)
    p_bench.add_argument("--precision", default="f64", help=argparse.SUPPRESS)
    add_fast_math_arg(p_bench, False)
    p_bench.set_defaults(func=cmd_bench)
    p_gal = sub.add_parser("gallery", help="every terrain x integrator video, a compare mosaic per terrain, "
                                              "and an index.html that shows them all")
    p_gal.add_argument("--terrains", metavar="A,B", help="comma-separated scene names (default: plane,tilted_plane,sphere,bowl,torus,three_cubes,pile)")
    p_gal.add_argument("--integrators", metavar="A,B", help="comma-separated integrator names (default: all registered)")
    p_gal.add_argument("--duration", type=float_arg("--duration"), help="simulated time [s] (default: each scene's)")
    p_gal.add_argument("--dt", type=float_arg("--dt"),
                       help="time step [s] for every run (default: the scene's for explicit methods, 1/60 s for implicit)")
    p_gal.add_argument("--resolution", type=resolution_arg, metavar="WxH",
                       help="size of each run's video (default 640x360; the compare mosaics are twice as wide and high)")
    p_gal.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="scene override for every run (repeatable)")
    p_gal.add_argument("--out", default=f"{DEFAULT_OUT}/gallery", help=f"output folder (default: {DEFAULT_OUT}/gallery)")
    add_task_args(p_gal)
    p_gal.set_defaults(func=cmd_gallery)
    p_list = sub.add_parser("list", help="list scenes, integrators and backends")
    p_list.set_defaults(func=cmd_list)
    return parser


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    previous = _catch_termination()
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if args.command is None:
            return main_job()
        return args.func(args)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OutputError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_OUTPUT
    except KeyboardInterrupt as e:
        signum = e.signum if isinstance(e, Terminated) else signal.SIGINT
        print(f"interrupted ({signal.Signals(signum).name}); no output was written or replaced", file=sys.stderr)
        return 128 + signum
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _catch_termination() -> dict:
    """SIGTERM and SIGHUP raise ``Terminated`` in the main thread (as SIGINT raises
    KeyboardInterrupt), so a killed run drops its temporary files; returns the old handlers."""
    def handler(signum, frame):
        raise Terminated(signum)

    previous = {}
    for signum in (signal.SIGTERM, signal.SIGHUP):
        try:
            previous[signum] = signal.signal(signum, handler)
        except ValueError:  # not the main thread (main() called from a worker): leave them
            pass
    return previous


def main_job() -> int:
    """``python main.py`` with no arguments: renders the default scene to out/<scene>-<integrator>.mp4."""
    return main(["run", "--scene", DEFAULT_SCENE, "--integrator", DEFAULT_INTEGRATOR,
                 "--video", f"{DEFAULT_OUT}/{DEFAULT_SCENE}-{DEFAULT_INTEGRATOR}.mp4"])
