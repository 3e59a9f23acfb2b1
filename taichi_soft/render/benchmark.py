"""Rendering cost per frame: ``python -m taichi_soft.render.benchmark [--resolution 1280x720]``.

Times each stage of a recorded frame on the default scene (a 1000-particle cube on the plane),
after a warm-up (Taichi compiles kernels and GGUI builds pipelines on first use), as medians
over repeats: surface update + draw + GPU readback, the uint8 conversion, the text overlay,
PNG writing and H.264 encoding (fed synchronously here, so its cost shows; in a run it happens on
the writer thread and in ffmpeg's own process).
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path


def _median_ms(fn, repeats: int) -> float:
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        samples.append(1000 * (time.perf_counter() - t0))
    return statistics.median(samples)


def main(argv=None) -> int:
    from ..runtime import init
    from ..scene import load_scene, parse_resolution
    from ..simulation import Simulation
    from . import overlay
    from .camera import scene_camera
    from .outputs import PngFrames, VideoFile
    from .renderer import Renderer, SimulationView, apply_camera, draw_view

    p = argparse.ArgumentParser(prog="python -m taichi_soft.render.benchmark", description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="plane")
    p.add_argument("--resolution", default="1280x720")
    p.add_argument("--repeats", type=int, default=30)
    args = p.parse_args(argv)
    width, height = parse_resolution(args.resolution)
    init("cpu", "f64")
    sim = Simulation(load_scene(args.scene))
    renderer = Renderer(width, height)
    view = SimulationView(sim)
    cam = scene_camera(sim.scene.data, width / height, top_margin=overlay.INFO_MARGIN)
    info = overlay.run_info(sim)
    energy0 = sim.measure()["total_energy"]
    sim.advance(1200)  # mid-bounce: a deformed cube in frame
    image = renderer.render(view, cam)
    lines = info.lines(sim.time, sim.measure()["total_energy"] - energy0)

    def render_only():
        view.update()
        apply_camera(renderer.scene, renderer.camera, cam)
        draw_view(renderer.canvas, renderer.scene, view)
        renderer.window.get_image_buffer_as_numpy()

    def readback():
        renderer.window.get_image_buffer_as_numpy()

    def convert():
        renderer.read_image()

    def with_overlay():
        overlay.draw_info(image.copy(), lines)

    stages = {}
    with tempfile.TemporaryDirectory() as tmp:
        video = VideoFile(Path(tmp) / "bench.mp4", 30.0, (width, height))
        pngs = PngFrames(Path(tmp) / "frames")
        counter = iter(range(10**9))
        for name, fn in (("render (update, draw, readback)", render_only), ("readback alone (GGUI, float32)", readback),
                         ("readback + uint8 conversion", convert),
                         ("measure (energies)", sim.measure), ("overlay (Pillow)", with_overlay),
                         ("PNG write", lambda: pngs.add(image, next(counter))),
                         ("H.264 encode (synchronous)", lambda: video.add(image, 0)),
                         ("whole frame as in a run", lambda: renderer.render(view, cam))):
            for _ in range(3):
                fn()  # warm-up
            stages[name] = _median_ms(fn, args.repeats)
        video.abort()
        pngs.abort()
    step_ms = _median_ms(lambda: sim.advance(33), 5)  # one 30 fps frame of simulation at dt = 1 ms
    renderer.close()
    print(f"{args.scene} at {width}x{height}, medians over {args.repeats} repeats:")
    for name, ms in stages.items():
        print(f"  {name:34s} {ms:8.2f} ms")
    print(f"  {'simulation, 1/30 s (33 steps)':34s} {step_ms:8.2f} ms  ({sim.integrator_name})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
