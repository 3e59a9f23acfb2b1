"""``run``: simulate a scene; write a summary, states, a video, frames, meshes and caches."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from .. import compile_notice
from ..errors import OutputError, raise_if_interrupted
from ..sim import error_estimate
from ..sim.memory import check_fits
from ..outfiles import finite_or_none
from . import common
from .common import (EXIT_DIVERGED, EXIT_OK, EXIT_OUTPUT, EXIT_UNRELIABLE, add_render_args, add_scene_args,
                     check_output_path, load_scene_from_args, print_outputs, render_options_from_args,
                     render_paths, runtime_args, write_output)


def add_parser(sub):
    """The ``run`` command's arguments on the subparsers ``sub``."""
    p_run = sub.add_parser("run", help="simulate a scene; write a summary, states (and video)")
    add_scene_args(p_run)
    p_run.add_argument("--summary", help="write a JSON run summary here")
    p_run.add_argument("--states", help="write sampled states (t, x, v) to this .npz")
    p_run.add_argument("--dry-run", action="store_true",
                       help="print what would be simulated and written and the memory estimate, then exit")
    p_run.add_argument("--error-estimate", action="store_true",
                       help="rerun at dt/2 and dt/4: the largest centre-of-mass and shape differences, the "
                            "extrapolated error for the method's order and whether the runs fit it (about 7x the run's cost)")
    p_run.add_argument("--tolerance", type=tolerance_arg, metavar="METRES",
                       help="run at the largest step whose error estimate meets this [m], halving from 0.9x the "
                            "method's linear stability limit (each try costs about 7 runs)")
    add_render_args(p_run)
    p_run.set_defaults(func=cmd_run)


MAX_HALVINGS = 10  # --tolerance: tries below the first step


def tolerance_arg(text: str) -> float:
    """--tolerance: a finite number of metres > 0."""
    import argparse
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--tolerance {text!r} is not a number") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"--tolerance {text!r}: must be a finite number of metres > 0")
    return value


def cmd_run(args) -> int:
    import numpy as np

    from ..progress import CountBar
    from ..sim.simulation import Simulation, body_lines, states_arrays, step_count

    scene = load_scene_from_args(args)
    check_fits(scene.data, None, args.precision, args.arch, record_states=args.states is not None,
               fast_math=args.fast_math)
    if args.dry_run:
        from ..dry_run import describe

        outputs = {"--summary": args.summary, "--states": args.states, "--video": args.video, "--frames": args.frames,
                   "--export-mesh": args.export_mesh, "--export-usd": args.export_usd, "--export-pc2": args.export_pc2}
        for line in describe(scene, args.precision, args.arch, outputs, scene.data["render"]["fps"], args.fast_math):
            print(line)
        return EXIT_OK
    summary_path = check_output_path(args.summary, "--summary", [".json"])
    states_path = check_output_path(args.states, "--states", [".npz"])
    render_options = render_options_from_args(args, scene)
    render_process = None
    if render_options.any and render_options.pipeline == "overlap":
        from ..render.pipeline import RenderProcess

        # Started first: its start-up (Python, Taichi, renderer, outputs) overlaps ours.
        render_process = RenderProcess(scene, render_options, runtime_args(args))
    try:
        common.start_taichi(args)
        sim = Simulation(scene)
    except BaseException:
        if render_process is not None:
            render_process.abort()
        raise
    compile_notice.watch()
    for line in body_lines(sim.model):
        print(line)
    duration = scene.sim["duration"]
    estimate = None
    if args.tolerance is not None:
        estimate = _step_for_tolerance(sim, duration, args.tolerance)
        if estimate is None:
            if render_process is not None:
                render_process.abort()
            return EXIT_UNRELIABLE
    elif args.error_estimate:
        estimate = error_estimate.estimate(sim, duration, sim.integrator.order)
    if estimate is not None:
        render_options.legend = (error_estimate.legend(estimate),)  # the video's overlay shows it too
    fps = scene.data["render"]["fps"]
    label = f"{scene.label}/{sim.integrator_name}"
    _note_whole_steps(duration, sim.dt)
    recorder, step_progress = None, None
    if render_options.any:
        from ..render.recorder import FrameRecorder, frame_count

        # Opens the offscreen window first: no Vulkan fails here, before any simulation.
        n_frames = frame_count(duration, sim.dt, fps)
        bar = CountBar(n_frames, label, unit="frame")
        progress = lambda k, s: bar.update(k, f"frame {k}/{n_frames} t={s.time:6.3f}s")  # noqa: E731
        if render_process is not None:
            from ..render.pipeline import OverlapRecorder

            recorder = OverlapRecorder(sim, render_options, render_process, progress=progress)
        else:
            recorder = FrameRecorder(sim, render_options, progress=progress)
    else:
        bar = CountBar(step_count(duration, sim.dt), label, unit="step")
        step_progress = lambda done, total, s: bar.update(done, f"t={s.time:6.3f}s")  # noqa: E731
    def on_frame(s):
        raise_if_interrupted()  # a Ctrl-C that a library swallowed (errors.received) stops the run here
        recorder(s)

    def on_progress(done, total, s):
        raise_if_interrupted()
        step_progress(done, total, s)

    try:
        result = sim.run(duration, fps, on_frame=None if recorder is None else on_frame,
                         record=states_path is not None, progress=None if step_progress is None else on_progress)
        raise_if_interrupted()  # before any output is committed
    except OutputError as e:  # the video or frames failed part-way (full disk, encoder error): stop there
        recorder.abort()
        others = [f"--{name} {path}" for name, path in (("summary", summary_path), ("states", states_path)) if path]
        raise OutputError(f"{e}; the run stopped at t = {sim.time:.3f} s" +
                          (f", so {' and '.join(others)} {'was' if len(others) == 1 else 'were'} not written either"
                           if others else "")) from None
    except BaseException:
        if recorder is not None:
            recorder.abort()
        raise
    finally:
        bar.close()
    failures = []
    written = []
    if recorder is not None:
        try:
            recorder.finish()
            written += list(zip(("video", "frames", "meshes", "usd", "pc2"), render_paths(render_options)))
        except OutputError as e:
            failures.append(str(e))
    summary = sim.summary(result)
    if estimate is not None:
        estimate["run_wall_seconds"] = result.wall_seconds
        summary["error_estimate"] = estimate
    if summary_path:
        text = json.dumps(finite_or_none(summary), indent=2)
        failures += write_output("summary", summary_path, lambda tmp: Path(tmp).write_text(text + "\n"), written)
    if states_path:
        arrays = states_arrays(result.frames, sim.model.real)

        def save(tmp):
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)
        failures += write_output("states", states_path, save, written)
    if not result.diverged:
        f = summary["final"]
        com = ", ".join(f"{c:.3f}" for c in f["center_of_mass"])
        print(f"{scene.label}/{sim.integrator_name}: {result.steps} steps of {sim.dt:g} s = {result.sim_time:.3f} s "
              f"simulated in {result.wall_seconds:.2f} s wall ({summary['steps_per_second']:.0f} steps/s); "
              f"final centre of mass ({com}), kinetic energy {f['kinetic_energy']:.3g} J")
    if estimate is not None:
        for line in error_estimate.lines(estimate):
            print(line)
    print_outputs(written)
    compile_notice.say_summary()
    for line in failures:
        print(f"error: {line}", file=sys.stderr)
    for line in summary["solver_warnings"]:
        print(f"warning: {label}: {line}", file=sys.stderr)
    if result.diverged:
        print(f"diverged at t = {result.diverged_at:.4f} s (step {result.diverged_step}) with {sim.integrator_name} "
              f"at dt = {sim.dt:g} s; {sim.divergence_hint()[1]}", file=sys.stderr)
        return EXIT_DIVERGED
    if summary["meaningless"]:
        print(f"error: {label}: the solver's fallbacks decided most steps, so this result is meaningless; "
              "try a smaller --dt or --precision f64", file=sys.stderr)
        return EXIT_UNRELIABLE
    return EXIT_OUTPUT if failures else EXIT_OK


def _note_whole_steps(duration: float, dt: float):
    """Say what is simulated when the duration is not a whole number of steps."""
    from ..sim.simulation import step_count

    steps = step_count(duration, dt)
    if abs(steps * dt - duration) > 1e-9 * duration:
        print(f"note: simulating {steps} steps of {dt:g} s = {steps * dt:g} s (sim.duration {duration:g} s "
              "is not a whole number of steps)", file=sys.stderr)


def _step_for_tolerance(sim, duration: float, tolerance: float) -> dict | None:
    """Set ``sim``'s dt to the largest step, halving from 0.9x the method's linear stability limit
    for the scene (the scene's dt for a method without one), whose error estimate fits the method's
    order and meets ``tolerance`` [m] on both measures; returns that estimate with the tries and
    their cost, or None (said on stderr) when no step down to MAX_HALVINGS halvings met it."""
    import math

    from ..sim.integrators import linear_stability

    w2, ratios = linear_stability.scene_modes(sim.model)
    limit = linear_stability.stable_limit(sim.integrator_name, w2, ratios)
    dt = linear_stability.round_down(0.9 * limit) if limit is not None and 0 < limit < math.inf else sim.dt
    tries, cost = [], 0.0
    for _ in range(MAX_HALVINGS + 1):
        sim.set_dt(dt)
        est = error_estimate.estimate(sim, duration, sim.integrator.order)
        cost += est["cost_seconds"]
        worst = None if not est["in_asymptotic_range"] else max(est["com_error"], est["shape_error"])
        tries.append({"dt": dt, "error": worst})
        print(f"tolerance {tolerance:g} m: dt = {dt:.3g} s: "
              + (f"estimated error {worst:.3g} m" if worst is not None else "no estimate (diverged, or the runs do "
                 "not fit the method's order)"))
        if worst is not None and worst <= tolerance:
            est["tolerance"] = tolerance
            est["tolerance_tries"] = tries
            est["tolerance_cost_seconds"] = cost
            print(f"tolerance {tolerance:g} m: running at dt = {dt:.3g} s (the search cost {cost:.2f} s of wall time)")
            return est
        dt /= 2
    print(f"error: no step down to {2 * dt:.3g} s met --tolerance {tolerance:g} m (the search cost {cost:.2f} s)",
          file=sys.stderr)
    return None
