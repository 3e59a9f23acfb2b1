"""``gallery``: every terrain x integrator video, a compare mosaic per terrain, index.html."""
from __future__ import annotations

import math
from pathlib import Path

from ..errors import UserError
from .common import (EXIT_OK, EXIT_TASKS_FAILED, check_output_dir, parse_integrator_list, parse_name_list)


def cmd_gallery(args) -> int:
    """``gallery``: every terrain x integrator video, a compare mosaic per terrain, index.html."""
    from ..gallery import DEFAULT_SCENES, PAGE, Plan, check_plan, run_gallery
    from ..render.outputs import check_video_size
    from ..scene import scene_names
    from ..tasks import make_executor, report_failures

    terrains = parse_name_list(args.terrains or ",".join(DEFAULT_SCENES), "--terrains", scene_names(), "scene",
                               "give distinct scene names separated by commas")
    from ..integrators import names

    integrators = parse_integrator_list(args.integrators or ",".join(names()))
    for flag, value in (("--duration", args.duration), ("--dt", args.dt)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise UserError(f"{flag} {value:g}: must be a positive number of seconds")
    from ..gallery import DEFAULT_RESOLUTION

    resolution = tuple(args.resolution or DEFAULT_RESOLUTION)
    check_video_size(Path("gallery.mp4"), *resolution)
    out = check_output_dir(args.out, "--out")
    plan = Plan(terrains, integrators, args.duration, resolution, args.dt, list(args.set), out)
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
