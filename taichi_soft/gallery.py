"""``python main.py gallery``: a video of every terrain x integrator pair, a ``compare`` mosaic per
terrain, and ``index.html``: one page (rows terrains, columns integrators) that works opened
from disk (relative links only, no server, no network; energy plots are inline SVG).

Each video is one task (``taichi_soft.tasks``): rendered in a fresh process, its bytes sent back
to the client, which writes every file through a temporary file and a rename. A failed task
gets a cell that says so, and the command exits non-zero.
"""
from __future__ import annotations

import html
import json
import math
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

from .outfiles import finite_or_none, write_atomic
from .tasks import Task, run_tasks

# The step each integrator gets unless --dt is given [s]: explicit methods the scene's own
# (1 ms in the shipped scenes, below their stable limit of about 1.8-2.6 ms,
# docs/benchmarks/stability_terrain.csv); implicit ones one step per 1/60 s, the step
# docs/implicit.md tests them at (stable there to 0.1 s on every terrain).
IMPLICIT_DT = 1.0 / 60.0
# The scenes a plain `gallery` renders: the cube on each terrain, a mesh body (the torus), and the
# scenes of several bodies (body-body contact with every integrator: three cubes on the plane, a
# pile of five in the bowl).
DEFAULT_SCENES = ("plane", "tilted_plane", "sphere", "bowl", "torus", "three_cubes", "pile")
DEFAULT_RESOLUTION = (640, 360)  # [px] of each single-run video; the mosaics are twice as wide and high
PAGE = "index.html"
MIN_ENERGY_SPAN = 1e-3  # smallest energy-axis range of the caption plots, relative to |E|


@dataclass
class Plan:
    """What to render: validated by the CLI before any task starts."""

    terrains: list  # scene names, e.g. ["plane", "bowl"]
    integrators: list  # registered integrator names
    duration: float | None  # [s], None: each scene's sim.duration
    resolution: tuple  # (width, height) [px] of each single-run video
    dt: float | None  # [s], None: per integrator (see run_dt)
    sets: list  # --set overrides applied to every run
    out: Path
    error_estimate: bool = False  # each single run also at dt/2 and dt/4: its estimated error in the caption


def run_dt(scene_dt: float, integrator: str, dt: float | None) -> float:
    """The step [s] ``integrator`` runs at in the gallery: ``dt`` if given, else its sensible default."""
    from .sim.integrators import REGISTRY

    if dt is not None:
        return dt
    cls = REGISTRY[integrator]
    if cls.implicit:
        return IMPLICIT_DT
    return scene_dt if cls.largest_default_dt is None else min(scene_dt, cls.largest_default_dt)


def video_name(terrain: str, integrator: str) -> str:
    return f"{terrain}_{integrator}.mp4"


def mosaic_resolution(resolution) -> tuple:
    return (2 * resolution[0], 2 * resolution[1])


def _load(terrain: str, sets, dt, duration, resolution):
    """The scene with the gallery's ``--set`` overrides, then dt, duration and resolution on top
    (as flags: they win over a ``--set`` of the same key, as in ``run``)."""
    from .sim.integrators import names
    from .sim.scene import load_scene

    flags = {"render.resolution": (list(resolution), f"--resolution {resolution[0]}x{resolution[1]}")}
    if dt is not None:
        flags["sim.dt"] = (dt, f"--dt {dt:g}")
    if duration is not None:
        flags["sim.duration"] = (duration, f"--duration {duration:g}")
    return load_scene(terrain, list(sets), integrator_names=names(), flags=flags)


def check_plan(plan: Plan) -> dict:
    """Load every scene with the plan's overrides (bad input raises ``UserError`` before any work);
    returns {terrain: scene dt [s]}."""
    from .sim.memory import check_fits

    dts = {}
    for terrain in plan.terrains:
        for res in (plan.resolution, mosaic_resolution(plan.resolution)):
            scene = _load(terrain, plan.sets, plan.dt, plan.duration, res)
        check_fits(scene.data, None, "f64", "cpu")  # one run's memory; tasks run one per process
        dts[terrain] = scene.sim["dt"]
    return dts


def build_tasks(plan: Plan, scene_dts: dict) -> list[Task]:
    """One task per (terrain, integrator) video, then one ``compare`` mosaic per terrain."""
    tasks = []
    common = {"duration": plan.duration, "sets": list(plan.sets)}
    for terrain in plan.terrains:
        for name in plan.integrators:
            tasks.append(Task(f"{terrain}/{name}", "taichi_soft.gallery:render_run",
                              dict(common, scene=terrain, integrator=name, resolution=tuple(plan.resolution),
                                   dt=run_dt(scene_dts[terrain], name, plan.dt), error_estimate=plan.error_estimate)))
        tasks.append(Task(f"{terrain}/compare", "taichi_soft.gallery:render_compare",
                          dict(common, scene=terrain, integrators=list(plan.integrators), dt=plan.dt,
                               resolution=mosaic_resolution(plan.resolution))))
    return tasks


# -- tasks (each in its own process: own Taichi runtime, own offscreen window) ----------------------
def render_run(scene: str, integrator: str, dt: float, duration, resolution, sets, error_estimate: bool = False) -> dict:
    """Render one run to an MP4; return its bytes, frame count, run summary and energy per frame,
    and with ``error_estimate`` the run's estimate (``sim.error_estimate.estimate``, also in the
    video's overlay)."""
    from . import runtime
    from .render import overlay
    from .render.recorder import FrameRecorder, RenderOptions
    from .sim import error_estimate as ee
    from .sim.integrators import scene_options
    from .sim.simulation import Simulation

    runtime.init("cpu", "f64")
    sc = _load(scene, sets, dt, duration, resolution)
    sim = Simulation(sc, integrator=integrator, options=scene_options(integrator, sc.data))
    fps = sc.data["render"]["fps"]
    energy = []
    estimate = ee.estimate(sim, sc.sim["duration"], sim.integrator.order) if error_estimate else None
    legend = () if estimate is None else (ee.legend(estimate),)
    with tempfile.TemporaryDirectory(prefix="taichi-soft-gallery-") as tmp:
        video = Path(tmp) / "run.mp4"
        recorder = FrameRecorder(sim, RenderOptions(video=video, fps=fps, resolution=tuple(resolution), legend=legend))

        def on_frame(s):
            recorder(s)
            if not s.diverged:
                energy.append((s.time, s.measure()["total_energy"]))

        try:
            result = sim.run(sc.sim["duration"], fps, on_frame=on_frame)
        except BaseException:
            recorder.abort()
            raise
        recorder.finish()
        data = video.read_bytes()
    info = overlay.run_info(sim)
    out = {"video": data, "frames": recorder.frames, "fps": fps, "summary": finite_or_none(sim.summary(result)),
           "energy": finite_or_none(energy), "stiffness": info.stiffness, "damping": info.damping}
    if estimate is not None:
        estimate["run_wall_seconds"] = result.wall_seconds
        out["error_estimate"] = finite_or_none(estimate)
    return out


def render_compare(scene: str, integrators: list, dt, duration, resolution, sets) -> dict:
    """Render one terrain's ``compare`` mosaic (all integrators at one dt) to an MP4."""
    from . import runtime
    from .render.compare import Comparison
    from .render.recorder import RenderOptions

    runtime.init("cpu", "f64")
    sc = _load(scene, sets, dt, duration, resolution)
    fps = sc.data["render"]["fps"]
    with tempfile.TemporaryDirectory(prefix="taichi-soft-gallery-") as tmp:
        video = Path(tmp) / "compare.mp4"
        comparison = Comparison(sc, list(integrators), RenderOptions(video=video, fps=fps, resolution=tuple(resolution)))
        frames = 0

        def count(k, t):
            nonlocal frames
            frames = k

        try:
            tiles = comparison.run(sc.sim["duration"], progress=count)
        except BaseException:
            comparison.abort()
            raise
        comparison.finish()
        data = video.read_bytes()
    return {"video": data, "frames": frames, "fps": fps, "dt": comparison.dt,
            "tiles": [finite_or_none(asdict(t)) for t in tiles]}


# -- the client: run the tasks, write files and the page ----------------------------------------------
def run_gallery(plan: Plan, executor, scene_dts: dict):
    """Run every task on ``executor``; write videos, ``gallery.json`` and ``index.html`` into
    ``plan.out``. Returns the ``Outcome`` (failed and unfinished tasks get a cell saying so)."""
    tasks = build_tasks(plan, scene_dts)
    plan.out.mkdir(parents=True, exist_ok=True)

    def write_video(key, res):  # as each task finishes: a crash later loses no finished video
        write_atomic(plan.out / video_name(*key.split("/")), lambda tmp: Path(tmp).write_bytes(res["video"]))
        return {k: v for k, v in res.items() if k != "video"}

    outcome = run_tasks(tasks, executor, label="gallery", on_result=write_video)
    cells = {}
    for task in tasks:
        res = outcome.results.get(task.key)
        cells[task.key] = {"video": video_name(*task.key.split("/")), "result": res,
                           "error": outcome.failed.get(task.key) or (None if res else "not run (interrupted)")}
    meta = {"terrains": plan.terrains, "integrators": plan.integrators, "duration": plan.duration,
            "resolution": list(plan.resolution), "sets": plan.sets, "cells": cells}
    write_atomic(plan.out / "gallery.json", lambda tmp: Path(tmp).write_text(json.dumps(meta, indent=1) + "\n"))
    text = page_html(plan, cells, outcome.wall_seconds)
    write_atomic(plan.out / PAGE, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))
    return outcome


def energy_svg(samples, diverged_at=None, width: int = 220, height: int = 56) -> str:
    """A small inline SVG line of total energy [J] against time [s], with its range written on it;
    ``width`` x ``height`` is its drawing's aspect (the page scales it to the card's width)."""
    pts = [(t, e) for t, e in samples if e is not None and math.isfinite(e)]
    if len(pts) < 2:
        return f'<svg class="energy" viewBox="0 0 {width} {height}" role="img" aria-label="no energy samples"></svg>'
    t0, t1 = pts[0][0], pts[-1][0]
    e_min, e_max = lo, hi = min(e for _, e in pts), max(e for _, e in pts)
    # The axis spans at least MIN_ENERGY_SPAN of the energy's size, so round-off wiggles of a
    # conserving method do not fill the plot.
    floor = MIN_ENERGY_SPAN * max(abs(lo), abs(hi), 1.0)
    if hi - lo < floor:
        mid = (hi + lo) / 2
        lo, hi = mid - floor / 2, mid + floor / 2
    span_t, span_e = (t1 - t0) or 1.0, hi - lo
    pad = 12  # px left free at the top and bottom for the labels

    def xy(t, e):
        return (width * (t - t0) / span_t, pad + (height - 2 * pad) * (1 - (e - lo) / span_e))

    line = " ".join("%.1f,%.1f" % xy(t, e) for t, e in pts)
    mark = ""
    if diverged_at is not None and span_t:
        x = width * min(max((diverged_at - t0) / span_t, 0.0), 1.0)
        mark = f'<line x1="{x:.1f}" y1="0" x2="{x:.1f}" y2="{height}" class="div"/>'
    return (f'<svg class="energy" viewBox="0 0 {width} {height}" role="img" '
            f'aria-label="total energy from {e_min:.6g} to {e_max:.6g} J over {t0:g}..{t1:g} s">'
            f'<polyline points="{line}"/>{mark}'
            f'<text x="2" y="10">E max {e_max:.6g} J</text><text x="2" y="{height - 2}">min {e_min:.6g} J, '
            f't {t0:g}..{t1:.3g} s</text></svg>')


def _caption(cell: dict) -> str:
    res, esc = cell["result"], html.escape
    if res is None:
        return f'<p class="failed">{esc(cell["error"])}</p>'
    if "summary" in res:
        s = res["summary"]
        diverged = (f'<span class="bad">diverged at t = {s["diverged_at"]:.4f} s</span>' if s["diverged"]
                    else "did not diverge")
        final = s["final"]["total_energy"]
        lines = [f"dt = {s['dt']:g} s, k = {esc(res['stiffness'])}", diverged,
                 f"final energy {'-' if final is None else format(final, '.6g') + ' J'}",
                 f"wall time {s['wall_seconds']:.1f} s (simulate + render), {res['frames']} frames"]
        est = res.get("error_estimate")
        if est is not None:
            from .sim.error_estimate import legend

            lines.append(f"{esc(legend(est))} (from runs at dt/2 and dt/4, {est['cost_seconds']:.1f} s)")
        plot = energy_svg(res["energy"], s["diverged_at"])
    else:
        lines = [f"all integrators at dt = {res['dt']:g} s, {res['frames']} frames"]
        for t in res["tiles"]:
            state = (f'<span class="bad">diverged at t = {t["diverged_at"]:.4f} s</span>' if t["diverged_at"] is not None
                     else f"E - E(0) = {t['final_energy']:+.6g} J" if t["final_energy"] is not None else "E - E(0) = -")
            lines.append(f"{esc(t['integrator'])}: {state}")
        plot = ""
    return "<br>".join(lines) + plot


STYLE = """
body { font: 13px/1.35 system-ui, sans-serif; margin: 16px; background: #f6f6f4; color: #222; }
.grid { display: grid; gap: 10px; align-items: start; }
.head { font-weight: 600; padding: 4px; }
.row { font-weight: 600; writing-mode: vertical-rl; transform: rotate(180deg); align-self: center; }
figure.cell { margin: 0; background: #fff; border: 1px solid #ddd; padding: 6px; overflow-wrap: anywhere; }
figure.cell video { width: 100%; display: block; background: #000; }
figcaption { margin-top: 4px; }
.bad, .failed { color: #b00; font-weight: 600; }
svg.energy { display: block; box-sizing: border-box; width: 100%; height: auto; margin-top: 4px; background: #fafafa;
              border: 1px solid #eee; }
svg.energy polyline { fill: none; stroke: #1f5fa8; stroke-width: 1.5; }
svg.energy line.div { stroke: #b00; stroke-dasharray: 3 2; }
svg.energy text { font-size: 9px; fill: #666; }
"""

# Says so in a cell when this browser cannot play a video (no codec, missing file). A video may have
# failed before this script runs (the parser can yield to the failed load first): check, then listen.
SCRIPT = """
document.querySelectorAll("video").forEach(function (v) {
  function say() {
    if (v.dataset.failed) return;
    v.dataset.failed = "1";
    var p = document.createElement("p"); p.className = "failed";
    p.textContent = "this browser could not load " + v.getAttribute("src");
    v.parentNode.insertBefore(p, v.nextSibling);
  }
  v.addEventListener("error", say, true);
  if (v.error) say();
});
"""


def page_html(plan: Plan, cells: dict, wall_seconds: float) -> str:
    """The gallery page: a CSS grid, rows terrains, columns integrators then the compare mosaic."""
    esc = html.escape
    cols = plan.integrators + ["compare"]
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             "<title>taichi-soft gallery</title>", f"<style>{STYLE}</style></head><body>",
             "<h1>taichi-soft gallery</h1>",
             f"<p>{len(plan.terrains)} terrains x {len(plan.integrators)} integrators"
             f"{', duration ' + format(plan.duration, 'g') + ' s' if plan.duration else ''}, "
             f"{plan.resolution[0]}x{plan.resolution[1]} px per run"
             f"{', --set ' + esc(' '.join(plan.sets)) if plan.sets else ''}"
             f"{', each run with its error estimate' if plan.error_estimate else ''}; all tasks took {wall_seconds:.0f} s. "
             f'Data: <a href="gallery.json">gallery.json</a>.</p>',
             f'<div class="grid" style="grid-template-columns: 2em repeat({len(cols)}, minmax(120px, 1fr));">',
             '<div></div>'] + [f'<div class="head">{esc(c)}</div>' for c in cols]
    for terrain in plan.terrains:
        parts.append(f'<div class="row">{esc(terrain)}</div>')
        for c in cols:
            cell = cells[f"{terrain}/{c}"]
            video = (f'<video src="{esc(cell["video"])}" controls muted loop playsinline preload="auto"></video>'
                     if cell["result"] is not None else "")
            parts.append(f'<figure class="cell" id="{esc(terrain)}-{esc(c)}">{video}'
                         f"<figcaption><b>{esc(terrain)} / {esc(c)}</b><br>{_caption(cell)}</figcaption></figure>")
    parts += ["</div>", f"<script>{SCRIPT}</script>", "</body></html>", ""]
    return "\n".join(parts)
