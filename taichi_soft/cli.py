"""Command line: ``python main.py [run|list|...]``.

Exit status: 0 success, 2 bad input (one line on stderr, nothing overwritten), 3 the run
diverged (summary and states so far are still written), 4 an output could not be written (one
line per output; each keeps its old file), 5 a sweep's task failed every attempt (the others' outputs are
still written), 130 / 143 / 129 interrupted by SIGINT / SIGTERM / SIGHUP (nothing half-written is
left; a sweep keeps what finished).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
from pathlib import Path

from .errors import OutputError, Terminated, UserError
from .memory import check_fits
from .outfiles import finite_or_none, probe_writable, remove_stale_temps, write_atomic

EXIT_OK, EXIT_BAD_INPUT, EXIT_DIVERGED, EXIT_OUTPUT, EXIT_TASKS_FAILED, EXIT_UNRELIABLE = 0, 2, 3, 4, 5, 6
EXIT_REPLAY_DIFFERS = 7  # demo --replay ended in another state than the recorded session
# The main job (`python main.py`): the assignment's cube dropped on the plane.
DEFAULT_SCENE, DEFAULT_INTEGRATOR = "plane", "rk4"
DEFAULT_COMPARE = "explicit_euler,semi_implicit_euler,midpoint,rk4"
DEFAULT_OUT = "out"  # the default outputs' folder, created when missing (no other folder is)


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error in one line and exits 2."""

    def error(self, message):
        raise UserError(f"{self.prog}: {message} (see --help)")


class _Choices(list):
    """Choices argparse accepts (``in``) beyond those it lists (iteration: help, usage, errors), for
    internal commands such as ``bench speed-worker`` (one benchmark process of ``bench report``)."""

    def __init__(self, shown, hidden):
        super().__init__(shown)
        self.hidden = set(hidden)

    def __contains__(self, item):
        return item in self.hidden or super().__contains__(item)


# -- output files --------------------------------------------------------------------------
def check_output_path(path: str | None, flag: str, suffixes=None) -> Path | None:
    """Fail early (before any simulation) if ``path`` cannot be written (a missing parent folder is
    created only inside the project's default ``out/``). Removes, and names on stderr, temporaries
    that killed runs left beside it."""
    if path is None:
        return None
    p = Path(path)
    if p.is_dir():
        raise UserError(f"{flag} {path}: is a directory, expected a file path")
    if suffixes and p.suffix.lower() not in suffixes:
        raise UserError(f"{flag} {path}: expected a file ending in {' or '.join(suffixes)}")
    _check_parent(p, flag, path)
    if p.exists() and not os.access(p, os.W_OK):
        raise UserError(f"{flag} {path}: file exists and is not writable")
    _note_removed(remove_stale_temps(p))
    return p


def check_output_dir(path: str | None, flag: str) -> Path | None:
    """Like ``check_output_path`` for a folder of numbered files (written beside it, then moved in)."""
    if path is None:
        return None
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise UserError(f"{flag} {path}: exists and is not a directory")
    _check_parent(p, flag, path)
    if p.exists() and not os.access(p, os.W_OK):
        raise UserError(f"{flag} {path}: directory is not writable")
    _note_removed(remove_stale_temps(p, inside=True))
    return p


def _note_removed(lines: list[str]):
    for line in lines:
        print(f"note: {line}", file=sys.stderr)


def _check_parent(p: Path, flag: str, path: str):
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        if parent.exists():
            raise UserError(f"{flag} {path}: {parent} is not a directory")
        if not _in_default_out(parent):
            raise UserError(f"{flag} {path}: directory {parent} does not exist (create it first; only the "
                            f"default {DEFAULT_OUT}/ is created for you)")
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise UserError(f"{flag} {path}: cannot create directory {parent}: {e.strerror}") from None
    if not os.access(parent, os.W_OK):
        raise UserError(f"{flag} {path}: directory {parent} is not writable")
    try:
        probe_writable(parent)
    except (OSError, OutputError) as e:
        reason = e.strerror if isinstance(e, OSError) else str(e)
        raise UserError(f"{flag} {path}: cannot create files in {parent}: {reason}") from None


def _in_default_out(folder: Path) -> bool:
    """Whether ``folder`` is the project's default output folder ``out/`` (of the current directory)
    or inside it: the one place outputs may create folders."""
    out = (Path.cwd() / DEFAULT_OUT).resolve()
    target = folder.resolve()
    return target == out or out in target.parents


# -- commands --------------------------------------------------------------------------------
def add_scene_args(p: argparse.ArgumentParser, integrator_default_help="the scene's", integrator=True):
    from .runtime import ARCHS, FAST_MATH_CLI_DEFAULT, PRECISIONS

    p.add_argument("--scene", default="plane", help="scene name in scenes/ or a path to a .toml file (default: plane)")
    if integrator:
        p.add_argument("--integrator", help=f"integrator name (default: {integrator_default_help} sim.integrator); see `list`")
    p.add_argument("--dt", type=_float_arg("--dt"), help="time step [s] (default: the scene's sim.dt)")
    p.add_argument("--duration", type=_float_arg("--duration"), help="simulated time [s] (default: the scene's sim.duration)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene key by dotted path, e.g. body.0.stretch.k=5000 (repeatable)")
    p.add_argument("--arch", default="cpu", choices=None, help=f"backend: {', '.join(ARCHS)} (default: cpu)")
    p.add_argument("--precision", default="f64", help=f"float precision: {', '.join(PRECISIONS)} (default: f64)")
    add_fast_math_arg(p, FAST_MATH_CLI_DEFAULT)


def add_fast_math_arg(p: argparse.ArgumentParser, default: bool):
    """--fast-math/--no-fast-math (why the defaults: runtime.FAST_MATH_CLI_DEFAULT)."""
    p.add_argument("--fast-math", action=argparse.BooleanOptionalAction, default=default,
                   help="fast floating-point arithmetic in the kernels (FMA contraction, reordering): the same "
                        f"physics to rounding; NaN/inf still stop the run (default: {'on' if default else 'off'})")


def add_render_args(p: argparse.ArgumentParser, mesh_export=True):
    """Flags for offscreen rendering (docs/rendering.md)."""
    from .render.export import MESH_FORMATS

    from .render.choose import RENDERERS

    g = p.add_argument_group("rendering (offscreen: GGUI on a Vulkan GPU, else Taichi kernels on the CPU)")
    g.add_argument("--video", metavar="PATH", help="write a video: .mp4 (H.264, yuv420p) or .gif")
    g.add_argument("--frames", metavar="DIR", help="write numbered PNGs DIR/frame_00000.png ...")
    g.add_argument("--fps", type=_float_arg("--fps"), help="output frames per simulated second (default: the scene's render.fps)")
    g.add_argument("--resolution", type=_resolution_arg, metavar="WxH",
                   help="frame size in pixels, e.g. 1280x720 (default: the scene's render.resolution)")
    g.add_argument("--particles", action="store_true", help="draw every particle as a small sphere")
    g.add_argument("--springs", action="store_true", help="draw springs: stretch blue, shear green, bend magenta")
    g.add_argument("--no-surface", dest="surface", action="store_false", help="do not draw the bodies' surfaces")
    g.add_argument("--follow", action=argparse.BooleanOptionalAction, default=None,
                   help="camera tracks the bodies' centre of mass (default: on tilted_plane and sphere, where they travel far)")
    g.add_argument("--no-overlay", dest="overlay", action="store_false", help="leave the text overlay out of frames")
    g.add_argument("--renderer", choices=RENDERERS, default="auto",
                   help="ggui: GGUI through Vulkan; taichi: Taichi kernels, no Vulkan needed, surfaces only; "
                        "auto (default): ggui on a Vulkan GPU or for --particles/--springs, else taichi")
    if mesh_export:
        g.add_argument("--export-mesh", metavar="DIR",
                       help="write each frame's surface mesh to DIR/mesh_00000.<fmt>, all bodies merged in one "
                            "file per frame (PLY: a 'body' index per vertex; OBJ: one object per body); "
                            "needs no Vulkan")
        g.add_argument("--mesh-format", choices=MESH_FORMATS, default="ply", help="mesh file format (default: ply)")
        g.add_argument("--export-usd", metavar="PATH",
                       help="write one USD stage (.usd, .usda or .usdc): each body a mesh with its points sampled "
                            "once per frame, the terrain static, Y up, metres (Blender, Houdini: docs/rendering.md); "
                            "needs no Vulkan")
        g.add_argument("--export-pc2", metavar="DIR",
                       help="write DIR/body_<b>.pc2 (Point Cache 2, one sample per frame) and the rest-pose "
                            "DIR/body_<b>.obj per body, for Blender's Mesh Cache modifier; needs no Vulkan")


def render_options_from_args(args, scene):
    """Validated ``RenderOptions``: output paths checked (and parents created) before any simulation."""
    from .render.choose import choose_renderer
    from .render.outputs import VIDEO_SUFFIXES, check_video_size
    from .render.recorder import RenderOptions

    render = scene.data["render"]
    width, height = render["resolution"]
    video = check_output_path(args.video, "--video", VIDEO_SUFFIXES)
    check_video_size(video, width, height)
    if video or args.frames:  # a bad combination: exit 2 now, before any simulation
        choose_renderer(args.renderer, args.particles or args.springs)
    usd = getattr(args, "export_usd", None)
    if usd is not None:
        from .render.caches import USD_SUFFIXES, require_usd

        usd = check_output_path(usd, "--export-usd", USD_SUFFIXES)
        require_usd()
    return RenderOptions(
        video=video, frames=check_output_dir(args.frames, "--frames"),
        mesh_dir=check_output_dir(getattr(args, "export_mesh", None), "--export-mesh"),
        usd=usd, pc2_dir=check_output_dir(getattr(args, "export_pc2", None), "--export-pc2"),
        mesh_format=getattr(args, "mesh_format", "ply"), fps=render["fps"], resolution=(width, height),
        surface=args.surface, particles=args.particles, springs=args.springs, follow=args.follow, overlay=args.overlay,
        renderer=args.renderer)


def _resolution_arg(text):
    from .scene import parse_resolution

    try:
        return parse_resolution(text)
    except UserError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected WIDTHxHEIGHT, each from 16 to 8192, e.g. 1280x720") from None


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

    flags = {}
    for flag, key in (("integrator", "sim.integrator"), ("dt", "sim.dt"), ("duration", "sim.duration"),
                      ("fps", "render.fps"), ("resolution", "render.resolution")):
        value = getattr(args, flag, None)
        if value is not None:
            flags[key] = (value, f"--{flag} {value if not isinstance(value, list) else 'x'.join(map(str, value))}")
    return load_scene(args.scene, args.set, integrator_names=names(), flags=flags)


def start_taichi(args):
    from . import runtime

    return runtime.init(args.arch, args.precision, fast_math=args.fast_math)


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

    from .progress import CountBar
    from .simulation import Simulation, body_lines, states_arrays, step_count

    scene = load_scene_from_args(args)
    check_fits(scene.data, None, args.precision, args.arch, record_states=args.states is not None,
               fast_math=args.fast_math)
    if args.dry_run:
        from .dry_run import describe

        outputs = {"--summary": args.summary, "--states": args.states, "--video": args.video, "--frames": args.frames,
                   "--export-mesh": args.export_mesh, "--export-usd": args.export_usd, "--export-pc2": args.export_pc2}
        for line in describe(scene, args.precision, args.arch, outputs, scene.data["render"]["fps"], args.fast_math):
            print(line)
        return EXIT_OK
    summary_path = check_output_path(args.summary, "--summary", [".json"])
    states_path = check_output_path(args.states, "--states", [".npz"])
    render_options = render_options_from_args(args, scene)
    start_taichi(args)
    sim = Simulation(scene)
    for line in body_lines(sim.model):
        print(line)
    duration = scene.sim["duration"]
    fps = scene.data["render"]["fps"]
    label = f"{scene.label}/{sim.integrator_name}"
    _note_whole_steps(duration, sim.dt)
    recorder, step_progress = None, None
    if render_options.any:
        from .render.recorder import FrameRecorder, frame_count

        # Opens the offscreen window first: no Vulkan fails here, before any simulation.
        n_frames = frame_count(duration, sim.dt, fps)
        bar = CountBar(n_frames, label, unit="frame")
        recorder = FrameRecorder(sim, render_options,
                                 progress=lambda k, s: bar.update(k, f"frame {k}/{n_frames} t={s.time:6.3f}s"))
    else:
        bar = CountBar(step_count(duration, sim.dt), label, unit="step")
        step_progress = lambda done, total, s: bar.update(done, f"t={s.time:6.3f}s")  # noqa: E731
    try:
        result = sim.run(duration, fps, on_frame=recorder, record=states_path is not None, progress=step_progress)
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
            written += list(zip(("video", "frames", "meshes", "usd", "pc2"), _render_paths(render_options)))
        except OutputError as e:
            failures.append(str(e))
    summary = sim.summary(result)
    if summary_path:
        text = json.dumps(finite_or_none(summary), indent=2)
        failures += _write_output("summary", summary_path, lambda tmp: Path(tmp).write_text(text + "\n"), written)
    if states_path:
        arrays = states_arrays(result.frames, sim.model.real)

        def save(tmp):
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)
        failures += _write_output("states", states_path, save, written)
    if not result.diverged:
        f = summary["final"]
        com = ", ".join(f"{c:.3f}" for c in f["center_of_mass"])
        print(f"{scene.label}/{sim.integrator_name}: {result.steps} steps of {sim.dt:g} s = {result.sim_time:.3f} s "
              f"simulated in {result.wall_seconds:.2f} s wall ({summary['steps_per_second']:.0f} steps/s); "
              f"final centre of mass ({com}), kinetic energy {f['kinetic_energy']:.3g} J")
    _print_outputs(written)
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
    from .simulation import step_count

    steps = step_count(duration, dt)
    if abs(steps * dt - duration) > 1e-9 * duration:
        print(f"note: simulating {steps} steps of {dt:g} s = {steps * dt:g} s (sim.duration {duration:g} s "
              "is not a whole number of steps)", file=sys.stderr)


def _write_output(label: str, path: Path, write, written: list) -> list[str]:
    """Write one output atomically; on success add (label, path) to ``written``, else return its error."""
    try:
        write_atomic(path, write)
    except OutputError as e:
        return [f"{label}: {e}"]
    written.append((label, path))
    return []


def _render_paths(options) -> list:
    return [options.video, options.frames, options.mesh_dir, options.usd, options.pc2_dir]


def _print_outputs(labelled):
    for label, path in labelled:
        if path:
            print(f"{label}: {path}")


def parse_name_list(text: str, flag: str, known: list[str], kind: str, hint: str) -> list[str]:
    """Comma-separated ``text`` of flag ``flag`` -> names, each in ``known``, no repeats; else a
    ``UserError`` naming the ``kind`` of name that is unknown, or ``hint`` on how to write the list."""
    chosen = [n.strip() for n in text.split(",") if n.strip()]
    for n in chosen:
        if n not in known:
            raise UserError(f"{flag}: unknown {kind} {n!r}; choose from: {', '.join(known)}")
    if not chosen or len(set(chosen)) != len(chosen):
        raise UserError(f"{flag} {text!r}: {hint}")
    return chosen


def parse_integrator_list(text: str) -> list[str]:
    """``"explicit_euler,rk4"`` -> names, each registered, no repeats; else ``UserError``."""
    from .integrators import names

    return parse_name_list(text, "--integrators", names(), "integrator",
                           "give distinct names separated by commas, e.g. explicit_euler,rk4")


def cmd_compare(args) -> int:
    from .progress import CountBar

    integrators = parse_integrator_list(args.integrators)
    scene = load_scene_from_args(args)
    check_fits(scene.data, integrators, args.precision, args.arch, fast_math=args.fast_math)
    if args.video is None and args.frames is None:
        args.video = f"{DEFAULT_OUT}/compare-{scene.name}.mp4"
    render_options = render_options_from_args(args, scene)
    start_taichi(args)
    from .render.compare import Comparison
    from .render.recorder import frame_count

    comparison = Comparison(scene, integrators, render_options)
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
    _print_outputs(zip(("video", "frames"), (render_options.video, render_options.frames)))
    return EXIT_OK


def cmd_bench(args) -> int:
    """``bench accuracy|precision|stability|speed|memory|report``: measure and write CSV, PNG and Markdown (docs/benchmarks/REPORT.md)."""
    import time

    from . import runtime
    from .progress import CountBar
    from .tasks import RETRIES, make_executor

    if args.study == "speed-worker":  # internal: one (arch, precision) per process, JSON on stdout
        from .bench.report import run_speed_worker

        runtime.init(args.arch, args.precision, fast_math=args.fast_math,
                     kernel_profiler=os.environ.get("TAICHI_SOFT_PROFILE") == "1")
        print(json.dumps(run_speed_worker(args.quick)))
        return EXIT_OK
    if args.study in ("speed", "memory", "mesh") and (args.workers is not None or args.scheduler is not None):
        raise UserError(f"bench {args.study} runs one configuration at a time (its measurements need a quiet "
                        "machine); --workers/--scheduler apply to the accuracy and stability sweeps")
    default = f"{DEFAULT_OUT}/benchmarks-quick" if args.quick else "docs/benchmarks"
    out_dir = check_output_dir(args.out or default, "--out")
    if args.study == "mesh":  # mesh-body goals: build time and frame cost (bench/meshbody.py)
        from .bench import meshbody as mesh_bench

        runtime.init("cpu", "f64")
        result = mesh_bench.run(repeats=2 if args.quick else 5, frames=5 if args.quick else 20)
        out_dir.mkdir(parents=True, exist_ok=True)
        b = result["build"]
        print(f"build {mesh_bench.N}^3 body from {result['triangles']} triangles: {b['median_s']:.2f} s wall, "
              f"{b['cpu_median_s']:.2f} s CPU (goal 2 s)")
        for kind, f in result["frame"].items():
            print(f"frame mesh/cube at 1280x720, {kind}: " + (f["error"] if "error" in f else
                  f"{f['mesh_ms']:.1f} / {f['cube_ms']:.1f} ms = {f['ratio']:.2f}x (goal 1.5x)"))
        print(f"wrote {mesh_bench.write_report(result, out_dir)}")
        return EXIT_OK
    # Before any work: an unreachable --scheduler is refused here, in a few seconds.
    executor = make_executor(args.workers, args.scheduler) if args.study not in ("speed", "memory") else None
    out_dir.mkdir(parents=True, exist_ok=True)
    from .bench import report

    start = time.perf_counter()
    acc = stab = speed = mem = prec = None
    files = []
    try:
        if args.study in ("accuracy", "report"):
            acc = report.run_accuracy(args.quick, executor)
            files += report.write_accuracy(acc, out_dir)
        if args.study in ("precision", "report") and not (acc and acc["interrupted"]):
            prec = report.run_precision(args.quick, executor)
            files += report.write_precision(prec, out_dir)
        if args.study in ("stability", "report") and not any(r and r["interrupted"] for r in (acc, prec)):
            stab = report.run_stability(args.quick, executor)
            files += report.write_stability(stab, out_dir)
    finally:
        if executor is not None:
            executor.close()
    if args.study in ("speed", "report") and not any(r and r["interrupted"] for r in (acc, prec, stab)):
        runtime.init("cpu", "f64")  # speed_configs asks Taichi which backends this machine has
        bar = CountBar(1, "bench speed", unit="config")
        speed = report.run_speed(args.quick, lambda done, total, what: bar.update(done, what[:60], total=total))
        bar.close()
        files += report.write_speed(speed, out_dir)
    if args.study in ("memory", "report") and not any(r and r["interrupted"] for r in (acc, prec, stab, speed)):
        bar = CountBar(1, "bench memory", unit="size")
        mem = report.run_memory(args.quick, lambda done, total, what: bar.update(done, str(what)[:60], total=total))
        bar.close()
        files += report.write_memory(mem, out_dir)
    command = "python main.py bench " + args.study + (" --quick" if args.quick else "") + (f" --out {args.out}" if args.out else "")
    name = "REPORT.md" if args.study == "report" else f"{args.study.upper()}.md"
    md = report.write_report(out_dir, command, acc, stab, speed, time.perf_counter() - start, mem, name, prec)
    files.append(md.name)
    if acc:
        for case, data in acc["cases"].items():
            orders = ", ".join(f"{k} {v:.2f}" for k, v in data["orders"].items() if v is not None)
            print(f"fitted orders ({case}): {orders}")
    print(f"wrote {len(files)} files to {out_dir}: {md}")
    failed = {k: v for r in (acc, prec, stab) if r for k, v in r["failed"].items()}
    for key, err in failed.items():
        print(f"bench {args.study}: task {key} FAILED after {RETRIES + 1} attempts: {err}", file=sys.stderr)
    if any(r and r["interrupted"] for r in (acc, prec, stab, speed, mem)):
        return 130
    return EXIT_TASKS_FAILED if failed else EXIT_OK


def cmd_gallery(args) -> int:
    """``gallery``: every terrain x integrator video, a compare mosaic per terrain, index.html."""
    from .gallery import DEFAULT_SCENES, PAGE, Plan, check_plan, run_gallery
    from .render.outputs import check_video_size
    from .scene import scene_names
    from .tasks import make_executor, report_failures

    terrains = parse_name_list(args.terrains or ",".join(DEFAULT_SCENES), "--terrains", scene_names(), "scene",
                               "give distinct scene names separated by commas")
    from .integrators import names

    integrators = parse_integrator_list(args.integrators or ",".join(names()))
    for flag, value in (("--duration", args.duration), ("--dt", args.dt)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise UserError(f"{flag} {value:g}: must be a positive number of seconds")
    from .gallery import DEFAULT_RESOLUTION

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


def add_task_args(p: argparse.ArgumentParser):
    """--workers / --scheduler: where a sweep's independent runs go (docs/gallery.md)."""
    from .tasks import default_workers

    g = p.add_argument_group("execution (each run a fresh process; docs/gallery.md)")
    g.add_argument("--workers", type=int, metavar="N",
                   help=f"run N tasks at a time in local processes (default: all cores, {default_workers()} here)")
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help="send the tasks to an existing Dask cluster, e.g. tcp://10.0.0.5:8786 "
                        "(start it with `dask scheduler`, workers with `dask worker ADDRESS`)")


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
    start_taichi(args)
    from .demo.app import run_demo

    run_demo(args.scene, args.set, args.integrator, args.dt, tuple(scene.data["render"]["resolution"]),
             frames=args.frames, screenshot=screenshot, paused=args.paused, duration=args.duration,
             record=record)
    return EXIT_OK


def cmd_demo_replay(args) -> int:
    """demo --replay: a recorded session played back without a display into a video."""
    from . import runtime
    from .demo.capture import default_path
    from .demo.session import load_session, replay

    if args.record is not None:
        raise UserError("--record and --replay exclude each other")
    data = load_session(args.replay)  # a bad file fails here, before Taichi starts
    video = check_output_path(args.video, "--video", [".mp4", ".gif"])
    setup = data["setup"]
    runtime.init(setup.get("arch", "cpu"), setup.get("precision", "f64"), fast_math=setup.get("fast_math", False))
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


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="main.py", description="taichi-soft: mass-spring soft bodies on Taichi")
    sub = parser.add_subparsers(dest="command", parser_class=_Parser)
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
    add_render_args(p_cmp, mesh_export=False)
    p_cmp.set_defaults(func=cmd_compare)
    p_demo = sub.add_parser("demo", help="open the interactive classroom window (needs a display and Vulkan)")
    add_scene_args(p_demo)
    next(a for a in p_demo._actions if a.dest == "duration").help = \
        "stop the simulation at this simulated time [s] (R restarts; default: run on)"
    p_demo.add_argument("--resolution", type=_resolution_arg, metavar="WxH", default=[1280, 800],
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
    p_bench.add_argument("study", choices=_Choices(["accuracy", "precision", "stability", "speed", "memory", "report", "mesh"],
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
    p_gal.add_argument("--duration", type=_float_arg("--duration"), help="simulated time [s] (default: each scene's)")
    p_gal.add_argument("--dt", type=_float_arg("--dt"),
                       help="time step [s] for every run (default: the scene's for explicit methods, 1/60 s for implicit)")
    p_gal.add_argument("--resolution", type=_resolution_arg, metavar="WxH",
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
