"""``demo``: the classroom window, and ``--replay`` of a recorded session into a video."""
from __future__ import annotations

import sys
from pathlib import Path

from ..errors import UserError
from ..sim.memory import check_fits
from . import common
from .common import (EXIT_OK, EXIT_REPLAY_DIFFERS, add_scene_args, check_output_path, load_scene_from_args,
                     resolution_arg)


def add_parser(sub):
    """The ``demo`` command's arguments on the subparsers ``sub``."""
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


def cmd_demo(args) -> int:
    """The interactive window (docs/teaching.md); no display or Vulkan: one line, exit 2."""
    if args.replay is not None:
        return cmd_demo_replay(args)
    if args.video is not None:
        raise UserError("--video goes with --replay (the live window records with V)")
    scene = load_scene_from_args(args)  # bad input fails here, before Taichi starts
    check_fits(scene.data, None, args.precision, args.arch, fast_math=args.fast_math)
    screenshot = check_output_path(args.screenshot, "--screenshot", [".png"])
    record = check_output_path(args.record, "--record", [".json"])
    common.start_taichi(args)
    from ..demo.app import run_demo

    run_demo(args.scene, args.set, args.integrator, args.dt, tuple(scene.data["render"]["resolution"]),
             frames=args.frames, screenshot=screenshot, paused=args.paused, duration=args.duration,
             record=record)
    return EXIT_OK


def cmd_demo_replay(args) -> int:
    """demo --replay: a recorded session played back without a display into a video."""
    from .. import runtime
    from ..demo.capture import default_path
    from ..demo.replay import replay
    from ..demo.session import load_session

    if args.record is not None:
        raise UserError("--record and --replay exclude each other")
    data = load_session(args.replay)  # a bad file fails here, before Taichi starts
    video = check_output_path(args.video, "--video", [".mp4", ".gif"])
    setup = data["setup"]
    runtime.init(setup.get("arch", "cpu"), setup.get("precision", "f64"), fast_math=setup.get("fast_math", False),
                 pin_threads=runtime.PIN_THREADS_CLI_DEFAULT)
    if video is None:
        video = default_path("replay", Path(str(setup["scene"])).stem, ".mp4")
    result = replay(data, video)
    deviation = result["max_deviation_m"]
    print(f"replay: {result['frames']} frames, {result['steps']} steps to t = {result['time']:.4f} s; video {result['video']}")
    if deviation is None:
        print("replay: the session holds no final state to compare with")
    elif deviation > 0:
        print(f"replay: the final state differs from the recorded session's by up to {deviation:.3g} m",
              file=sys.stderr)
        return EXIT_REPLAY_DIFFERS
    else:
        print("replay: final state identical to the recorded session's")
    return EXIT_OK
