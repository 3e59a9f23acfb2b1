"""Rendering cost per frame, stage by stage: ``python -m taichi_soft.render.benchmark``.

    python -m taichi_soft.render.benchmark [--scene plane,sphere] [--resolution 640x360,1280x720]
                                           [--renderer ggui,taichi] [--repeats 15]

For each scene, resolution and renderer: one frame of the scene mid-motion (1.2 s in), each
stage timed alone after a warm-up (Taichi compiles kernels and GGUI builds pipelines on first
use), the stages in turn round after round, medians over the rounds, wall clock and CPU time of
the whole process (all its threads: Taichi's, lavapipe's; the CPU figure moves less when other
programs share the cores, and a frame whose CPU time is under a budget fits that budget in wall
time on one idle core):

- update + lighting: surface positions and normals, lighting per vertex (``lighting.shade``)
- draw: GGUI draw and read-back (float32; GGUI draws inside its read-back call), also with GGUI
  lighting every pixel (the look before per-vertex lighting, for comparison); for the Taichi
  rasterizer the whole frame at each ``--quality`` (low, medium, high), each by its own renderer
- read-back: GGUI's read-back of an empty frame (its fixed cost: clear, draw nothing, copy)
- conversion: GGUI's float32 image to uint8 RGB (``readback.py``)
- overlay (Pillow), encode (H.264: writing the frame to ffmpeg's pipe; ffmpeg encodes in its own
  process), simulation of one 30 fps frame (33 steps)
- whole frame: what a run's main thread does per frame (render: update, light, draw, read-back,
  conversion), then **the pipelines**, a run's own loop (simulate 1/30 s, then the frame's
  labels, render, overlay, encode) with each ``--pipeline``: serial (``FrameRecorder``: render
  here, overlay and encode on the writer thread) and overlap (``OverlapRecorder``: a render
  process draws, overlays and encodes beside the simulation, ``pipeline.py``; CPU of both
  processes), 3 rounds of 10 frames each in turn, wall time per frame, and the overlap each
  achieved = (sum of the stages) / (pipeline time per frame).
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path


def _interleaved_ms(stages: dict, repeats: int, warmup: int = 3) -> dict:
    """{name: (wall, process CPU) medians in ms} of each ``stages[name]()``, the stages timed in
    turn, round after round (a load that drifts hits all of them alike); ``ti.sync()`` before
    each clock read (``taichi_soft.timing``)."""
    from ..timing import Candidate, time_candidates

    timings = time_candidates({name: Candidate(fn, warmup=lambda fn=fn: [fn() for _ in range(warmup)])
                               for name, fn in stages.items()}, repeats, rotate=False)
    return {name: (1000 * t.median, 1000 * t.cpu_median) for name, t in timings.items()}


def _stages(renderer, kind, view, cam, sim, info, width, height, repeats, tmp):
    """{stage: (wall ms, cpu ms)} for one renderer on one view."""
    from . import overlay
    from .lighting import light_rig
    from .outputs import VideoFile
    from .renderer import BACKGROUND, apply_camera, draw_view

    image = renderer.render(view, cam)
    lines = info.lines(sim.time, sim.measure()["total_energy"])
    stages = {"update + lighting": lambda: (view.update(), view.light(light_rig(cam), (cam, width, height)))}
    if kind == "ggui":
        def draw():
            apply_camera(renderer.scene, renderer.camera, cam)
            draw_view(renderer.canvas, renderer.scene, view)
            renderer.window.get_image_buffer_as_numpy()

        def empty_readback():
            apply_camera(renderer.scene, renderer.camera, cam)
            renderer.canvas.set_background_color(BACKGROUND)
            renderer.canvas.scene(renderer.scene)
            renderer.window.get_image_buffer_as_numpy()

        buf = renderer.window.get_image_buffer_as_numpy()
        from .readback import float_image_to_rgb8
        import numpy as np

        rgb = np.empty((height, width, 3), np.uint8)
        def draw_per_pixel():
            view.per_pixel_lighting = True
            draw()
            view.per_pixel_lighting = False

        stages["draw + read-back (GGUI)"] = draw
        stages["  the same, lit per pixel (old)"] = draw_per_pixel
        stages["read-back alone (empty frame)"] = empty_readback
        stages["conversion to uint8"] = lambda: float_image_to_rgb8(buf, rgb)
    else:
        from .quality import QUALITIES
        from .taichi_renderer import TaichiRenderer

        # Each quality by its own renderer, timed in the same rounds (terrain kept while the camera
        # holds, as in a run with a fixed camera).
        for quality in QUALITIES:
            other = renderer if quality == renderer.quality else TaichiRenderer(width, height, quality)
            stages[f"whole frame, quality {quality}"] = lambda other=other: other.render(view, cam)
    video = VideoFile(Path(tmp) / f"bench-{kind}.mp4", 30.0, (width, height))
    stages["overlay (Pillow)"] = lambda: overlay.draw_info(image.copy(), lines)
    stages["encode (to ffmpeg's pipe)"] = lambda: video.add(image, 0)
    stages["whole frame (render)"] = lambda: renderer.render(view, cam)
    stages["simulation (1/30 s, 33 steps)"] = lambda: sim.advance(33)
    times = _interleaved_ms(stages, repeats)
    video.abort()
    return times


SERIAL, OVERLAP = "pipeline: serial, per frame", "pipeline: overlap, per frame"
RUNTIME = {"arch": "cpu", "precision": "f64", "fast_math": True}  # as the command line runs


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time [s] of process ``pid`` so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _pipelines(sim, kind, width, height, tmp, rounds: int = 3, frames: int = 10) -> dict:
    """{name: (wall, CPU) ms per frame} of a run's loop with each ``--pipeline``, the run's own
    code: simulate 1/30 s, then ``FrameRecorder`` (serial: render here, overlay and encode on the
    writer thread) or ``OverlapRecorder`` (overlap: hand the positions to the render process,
    which draws, overlays and encodes; CPU of both processes). After 5 warm-up frames each,
    ``rounds`` x ``frames`` frames, the two pipelines in turn, each timed until every frame is in
    ffmpeg's pipe (ffmpeg's own CPU in neither)."""
    from .pipeline import OverlapRecorder, RenderProcess
    from .recorder import FrameRecorder, RenderOptions

    def options(pipeline):
        return RenderOptions(video=Path(tmp) / f"bench-{kind}-{pipeline}.mp4", resolution=(width, height),
                             renderer=kind, pipeline=pipeline)

    runs = {}
    try:
        serial = FrameRecorder(sim, options("serial"))
        runs[SERIAL] = (serial, serial.writer.flush, lambda: 0.0)
        render = RenderProcess(sim.scene, options("overlap"), RUNTIME)
        runs[OVERLAP] = (OverlapRecorder(sim, options("overlap"), render), render.sync,
                         lambda: _cpu_seconds(render.proc.pid))
        for recorder, sync, _ in runs.values():  # warm-up: kernels, the render process's first frames
            for _ in range(5):
                sim.advance(33)
                recorder(sim)
            sync()
        spent = {name: [0.0, 0.0] for name in runs}
        for _ in range(rounds):
            for name, (recorder, sync, others) in runs.items():
                t0, c0, r0 = time.perf_counter(), time.process_time(), others()
                for _ in range(frames):
                    sim.advance(33)
                    recorder(sim)
                sync()
                spent[name][0] += time.perf_counter() - t0
                spent[name][1] += time.process_time() - c0 + others() - r0
    finally:
        for recorder, _, _ in runs.values():
            recorder.abort()
    n = rounds * frames
    return {name: (1000 * wall / n, 1000 * cpu / n) for name, (wall, cpu) in spent.items()}


def main(argv=None) -> int:
    from ..errors import UserError
    from ..runtime import init
    from ..sim.scene import load_scene
    from ..sim.scene_validation import parse_resolution
    from ..sim.simulation import Simulation
    from . import overlay
    from .camera import scene_camera
    from .renderer import Renderer, SimulationView
    from .taichi_renderer import TaichiRenderer

    p = argparse.ArgumentParser(prog="python -m taichi_soft.render.benchmark", description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="plane", help="comma-separated scene names (default: plane)")
    p.add_argument("--resolution", default="1280x720", help="comma-separated WxH (default: 1280x720)")
    p.add_argument("--renderer", default="ggui,taichi", help="comma-separated: ggui, taichi (default: both)")
    p.add_argument("--repeats", type=int, default=15)
    args = p.parse_args(argv)
    kinds = args.renderer.split(",")
    if set(kinds) - {"ggui", "taichi"}:
        p.error(f"--renderer: choose from ggui, taichi, got {args.renderer}")
    try:  # bad input: one line and exit 2 before any work
        sizes = [parse_resolution(r) for r in args.resolution.split(",")]
        scenes = args.scene.split(",")
        for name in scenes:
            load_scene(name)
    except UserError as e:
        p.error(str(e))
    init(**RUNTIME)
    print(f"load average before: {', '.join(f'{x:.2f}' for x in os.getloadavg())} ({os.cpu_count()} cores)")
    with tempfile.TemporaryDirectory() as tmp:
        for name in scenes:
            for width, height in sizes:
                for kind in kinds:
                    sim = Simulation(load_scene(name))  # a fresh one per table
                    sim.advance(1200)  # mid-motion: a deformed body in frame
                    renderer = (Renderer if kind == "ggui" else TaichiRenderer)(width, height)
                    view = SimulationView(sim)
                    cam = scene_camera(sim.scene.data, width / height, top_margin=overlay.INFO_MARGIN)
                    cam = cam.following(sim.measure()["center_of_mass"])
                    times = _stages(renderer, kind, view, cam, sim, overlay.run_info(sim), width, height, args.repeats, tmp)
                    renderer.close()
                    times.update(_pipelines(sim, kind, width, height, tmp))
                    if kind == "taichi":  # its whole frame already holds the update and lighting
                        parts = ("whole frame (render)", "overlay (Pillow)", "encode (to ffmpeg's pipe)",
                                 "simulation (1/30 s, 33 steps)")
                        stage_sum = sum(times[k][0] for k in parts)
                    else:
                        stage_sum = sum(w for k, (w, _) in times.items()
                                        if k not in ("whole frame (render)", SERIAL, OVERLAP)
                                        and not k.startswith(("read-back alone", "  the same")))
                    print(f"\n{name} at {width}x{height}, {kind}, medians of {args.repeats} (wall / CPU of all threads):")
                    for stage, (wall, cpu) in times.items():
                        print(f"  {stage:32s} {wall:8.2f} ms {cpu:8.2f} ms")
                    pipe, beside = times[SERIAL][0], times[OVERLAP][0]
                    print(f"  overlap achieved: the stages sum to {stage_sum:.1f} ms; serial pipeline {pipe:.1f} ms "
                          f"a frame ({stage_sum / pipe:.2f}x), render process beside the simulation {beside:.1f} ms "
                          f"({stage_sum / beside:.2f}x)")
    print(f"\nload average after: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
