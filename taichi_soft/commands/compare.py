"""``compare``: one scene with several integrators at the same dt, one mosaic video."""
from __future__ import annotations

from .. import compile_notice
from ..sim.memory import check_fits
from . import common
from .common import (DEFAULT_OUT, EXIT_OK, add_render_args, add_scene_args, load_scene_from_args,
                     parse_integrator_list, print_outputs, render_options_from_args)


DEFAULT_COMPARE = "explicit_euler,semi_implicit_euler,midpoint,rk4"  # the integrators compared by default


def add_parser(sub):
    """The ``compare`` command's arguments on the subparsers ``sub``."""
    p_cmp = sub.add_parser("compare", help="run one scene with several integrators at the same dt; write a mosaic video")
    add_scene_args(p_cmp, integrator=False)
    p_cmp.add_argument("--integrators", default=DEFAULT_COMPARE,
                       help=f"comma-separated integrator names, one tile each (default: {DEFAULT_COMPARE})")
    add_render_args(p_cmp, mesh_export=False, pipeline=False)
    p_cmp.set_defaults(func=cmd_compare)


def cmd_compare(args) -> int:
    from ..progress import CountBar

    integrators = parse_integrator_list(args.integrators)
    scene = load_scene_from_args(args)
    check_fits(scene.data, integrators, args.precision, args.arch, fast_math=args.fast_math)
    if args.video is None and args.frames is None:
        args.video = f"{DEFAULT_OUT}/compare-{scene.name}.mp4"
    render_options = render_options_from_args(args, scene)
    common.start_taichi(args)
    from ..render.compare import Comparison
    from ..render.recorder import frame_count

    comparison = Comparison(scene, integrators, render_options)
    compile_notice.watch()
    n_frames = frame_count(scene.sim["duration"], comparison.dt, render_options.fps)
    bar = CountBar(n_frames, f"{scene.label}: {', '.join(integrators)}", unit="frame")
    try:
        results = comparison.run(scene.sim["duration"],
                                 progress=lambda k, t: bar.update(k, f"frame {k}/{n_frames} t={t:6.3f}s"))
    except BaseException:
        comparison.abort()
        raise
    finally:
        bar.close()
    comparison.finish()
    for r in results:
        if r.diverged_at is not None:
            state = f"diverged at t = {r.diverged_at:.4f} s (step {r.diverged_step})"
        else:
            state = f"ran to t = {r.final_time:.3f} s, energy change since t = 0 {r.final_energy:+.6g} J"
        print(f"{r.integrator:22s} dt = {comparison.dt:g} s: {state}")
    print_outputs(zip(("video", "frames"), (render_options.video, render_options.frames)))
    compile_notice.say_summary()
    return EXIT_OK
