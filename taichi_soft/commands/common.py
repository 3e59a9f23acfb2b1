"""What the commands share: the parser, argument helpers, output-path checks (refused before any
work, exit 2), the Taichi start-up from the flags, exit codes."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from ..errors import OutputError, UserError
from ..outfiles import probe_writable, remove_stale_temps, write_atomic

EXIT_OK, EXIT_BAD_INPUT, EXIT_DIVERGED, EXIT_OUTPUT, EXIT_TASKS_FAILED, EXIT_UNRELIABLE = 0, 2, 3, 4, 5, 6
EXIT_REPLAY_DIFFERS = 7  # demo --replay ended in another state than the recorded session
DEFAULT_OUT = "out"  # the default outputs' folder, created when missing (no other folder is)


class Parser(argparse.ArgumentParser):
    """argparse that reports a usage error in one line and exits 2."""

    def error(self, message):
        raise UserError(f"{self.prog}: {message} (see --help)")


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
    from ..runtime import ARCHS, FAST_MATH_CLI_DEFAULT, PRECISIONS

    p.add_argument("--scene", default="plane", help="scene name in scenes/ or a path to a .toml file (default: plane)")
    if integrator:
        p.add_argument("--integrator", help=f"integrator name (default: {integrator_default_help} sim.integrator); see `list`")
    p.add_argument("--dt", type=float_arg("--dt"), help="time step [s] (default: the scene's sim.dt)")
    p.add_argument("--duration", type=float_arg("--duration"), help="simulated time [s] (default: the scene's sim.duration)")
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


def add_render_args(p: argparse.ArgumentParser, mesh_export=True, pipeline=True):
    """Flags for offscreen rendering (docs/rendering.md); ``pipeline``: offer --pipeline (run only)."""
    from ..render.export import MESH_FORMATS

    from ..render.choose import RENDERERS
    from ..render.quality import DEFAULT_QUALITY, QUALITIES
    from ..render.pipeline import PIPELINES

    g = p.add_argument_group("rendering (offscreen: GGUI on a Vulkan GPU, else Taichi kernels on the CPU)")
    g.add_argument("--video", metavar="PATH", help="write a video: .mp4 (H.264, yuv420p) or .gif")
    g.add_argument("--frames", metavar="DIR", help="write numbered PNGs DIR/frame_00000.png ...")
    g.add_argument("--fps", type=float_arg("--fps"), help="output frames per simulated second (default: the scene's render.fps)")
    g.add_argument("--resolution", type=resolution_arg, metavar="WxH",
                   help="frame size in pixels, e.g. 1280x720 (default: the scene's render.resolution)")
    g.add_argument("--particles", action="store_true", help="draw every particle as a small sphere")
    g.add_argument("--springs", action="store_true", help="draw springs: stretch blue, shear green, bend magenta")
    g.add_argument("--no-surface", dest="surface", action="store_false", help="do not draw the bodies' surfaces")
    g.add_argument("--follow", action=argparse.BooleanOptionalAction, default=None,
                   help="camera tracks the bodies' centre of mass (default: on tilted_plane and sphere, where they travel far)")
    g.add_argument("--no-overlay", dest="overlay", action="store_false", help="leave the text overlay out of frames")
    if pipeline:
        g.add_argument("--pipeline", choices=PIPELINES, default="auto",
                       help="serial: simulate, then render each frame in this process; overlap: a render "
                            "process draws frame k while this one simulates frame k+1 (same states, bit for bit); "
                            "auto (default): overlap with --video/--frames, else serial (docs/rendering.md)")
    g.add_argument("--renderer", choices=RENDERERS, default="auto",
                   help="ggui: GGUI through Vulkan; taichi: Taichi kernels, no Vulkan needed, surfaces only; "
                        "auto (default): ggui on a Vulkan GPU or for --particles/--springs, else taichi")
    g.add_argument("--quality", choices=QUALITIES, default=DEFAULT_QUALITY,
                   help="the taichi renderer's look: low = as GGUI draws (checker filtered, no shadows); "
                        "medium = + the bodies' shadows from the key light; high = + antialiased edges (bodies "
                        f"2x2 samples a pixel, terrain 4x4 for a fixed camera) (default: {DEFAULT_QUALITY}; "
                        "GGUI draws no shadows: docs/rendering.md)")
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
    from ..render.choose import choose_renderer
    from ..render.outputs import VIDEO_SUFFIXES, check_video_size
    from ..render.pipeline import choose_pipeline
    from ..render.recorder import RenderOptions

    render = scene.data["render"]
    width, height = render["resolution"]
    video = check_output_path(args.video, "--video", VIDEO_SUFFIXES)
    check_video_size(video, width, height)
    if video or args.frames:  # a bad combination: exit 2 now, before any simulation
        choose_renderer(args.renderer, args.particles or args.springs)
    usd = getattr(args, "export_usd", None)
    if usd is not None:
        from ..render.caches import USD_SUFFIXES, require_usd

        usd = check_output_path(usd, "--export-usd", USD_SUFFIXES)
        require_usd()
    options = RenderOptions(
        video=video, frames=check_output_dir(args.frames, "--frames"),
        mesh_dir=check_output_dir(getattr(args, "export_mesh", None), "--export-mesh"),
        usd=usd, pc2_dir=check_output_dir(getattr(args, "export_pc2", None), "--export-pc2"),
        mesh_format=getattr(args, "mesh_format", "ply"), fps=render["fps"], resolution=(width, height),
        surface=args.surface, particles=args.particles, springs=args.springs, follow=args.follow, overlay=args.overlay,
        renderer=args.renderer, quality=args.quality)
    options.pipeline = choose_pipeline(getattr(args, "pipeline", "serial"), options)
    return options


def resolution_arg(text):
    from ..sim.scene_validation import parse_resolution

    try:
        return parse_resolution(text)
    except UserError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected WIDTHxHEIGHT, each from 16 to 8192, e.g. 1280x720") from None


def float_arg(flag):
    def parse(text):
        try:
            return float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} {text!r} is not a number") from None
    return parse


def load_scene_from_args(args):
    """Scene from --scene and --set, with --integrator/--dt/--duration applied on top."""
    from ..sim.integrators import names
    from ..sim.scene import load_scene

    flags = {}
    for flag, key in (("integrator", "sim.integrator"), ("dt", "sim.dt"), ("duration", "sim.duration"),
                      ("fps", "render.fps"), ("resolution", "render.resolution")):
        value = getattr(args, flag, None)
        if value is not None:
            flags[key] = (value, f"--{flag} {value if not isinstance(value, list) else 'x'.join(map(str, value))}")
    return load_scene(args.scene, args.set, integrator_names=names(), flags=flags)


def start_taichi(args):
    """Start Taichi as the command line asked; kernels' first launches are timed (compile_notice)."""
    import taichi as ti

    from .. import compile_notice, runtime

    started = runtime.init(**runtime_args(args))
    compile_notice.install(ti.lang.impl.current_cfg().offline_cache_file_path)
    return started


def runtime_args(args) -> dict:
    """``runtime.init``'s arguments from the command line (the render process starts its own)."""
    from .. import runtime

    return {"arch": args.arch, "precision": args.precision, "fast_math": args.fast_math,
            "pin_threads": runtime.PIN_THREADS_CLI_DEFAULT}


def write_output(label: str, path: Path, write, written: list) -> list[str]:
    """Write one output atomically; on success add (label, path) to ``written``, else return its error."""
    try:
        write_atomic(path, write)
    except OutputError as e:
        return [f"{label}: {e}"]
    written.append((label, path))
    return []


def render_paths(options) -> list:
    return [options.video, options.frames, options.mesh_dir, options.usd, options.pc2_dir]


def print_outputs(labelled):
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
    from ..sim.integrators import names

    return parse_name_list(text, "--integrators", names(), "integrator",
                           "give distinct names separated by commas, e.g. explicit_euler,rk4")


def add_task_args(p: argparse.ArgumentParser):
    """--workers / --scheduler: where a sweep's independent runs go (docs/gallery.md)."""
    from ..tasks import default_workers

    g = p.add_argument_group("execution (each run a fresh process; docs/gallery.md)")
    g.add_argument("--workers", type=int, metavar="N",
                   help=f"run N tasks at a time in local processes (default: all cores, {default_workers()} here)")
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help="send the tasks to an existing Dask cluster, e.g. tcp://10.0.0.5:8786 "
                        "(start it with `dask scheduler`, workers with `dask worker ADDRESS`)")
