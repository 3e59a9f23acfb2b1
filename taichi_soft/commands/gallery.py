"""``gallery``: every terrain x integrator video, a compare mosaic per terrain, index.html."""
from __future__ import annotations

import math
from pathlib import Path

from ..errors import UserError
from .common import (DEFAULT_OUT, EXIT_OK, EXIT_TASKS_FAILED, add_task_args, check_output_dir, float_arg,
                     parse_integrator_list, parse_name_list, resolution_arg)


def add_parser(sub):
    """The ``gallery`` command's arguments on the subparsers ``sub``."""
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
    p_gal.add_argument("--error-estimate", action="store_true",
                       help="each run also at dt/2 and dt/4: its estimated error in the caption and the video's "
                            "overlay (about 7x each run's simulation cost)")
    p_gal.add_argument("--out", default=f"{DEFAULT_OUT}/gallery", help=f"output folder (default: {DEFAULT_OUT}/gallery)")
    add_task_args(p_gal)
    p_gal.set_defaults(func=cmd_gallery)


def cmd_gallery(args) -> int:
    """``gallery``: every terrain x integrator video, a compare mosaic per terrain, index.html."""
    from ..gallery import DEFAULT_SCENES, PAGE, Plan, check_plan, run_gallery
    from ..render.outputs import check_video_size
    from ..sim.scene import scene_names
    from ..tasks import make_executor, report_failures

    terrains = parse_name_list(args.terrains or ",".join(DEFAULT_SCENES), "--terrains", scene_names(), "scene",
                               "give distinct scene names separated by commas")
    from ..sim.integrators import names

    integrators = parse_integrator_list(args.integrators or ",".join(names()))
    for flag, value in (("--duration", args.duration), ("--dt", args.dt)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise UserError(f"{flag} {value:g}: must be a positive number of seconds")
    from ..gallery import DEFAULT_RESOLUTION

    resolution = tuple(args.resolution or DEFAULT_RESOLUTION)
    check_video_size(Path("gallery.mp4"), *resolution)
    out = check_output_dir(args.out, "--out")
    plan = Plan(terrains, integrators, args.duration, resolution, args.dt, list(args.set), out,
                error_estimate=args.error_estimate)
    scene_dts = check_plan(plan)  # every scene and --set checked before any task
    executor = make_executor(args.workers, args.scheduler)
    try:
        outcome = run_gallery(plan, executor, scene_dts)
    finally:
        executor.close()
    report_failures(outcome, "gallery")
    done = len(outcome.results)
    print(f"gallery: {done} of {len(outcome.attempts)} videos in {outcome.wall_seconds:.1f} s on {executor.where}")
    print(f"page: {out / PAGE}")
    if outcome.interrupted:
        return 130
    return EXIT_TASKS_FAILED if outcome.failed else EXIT_OK
