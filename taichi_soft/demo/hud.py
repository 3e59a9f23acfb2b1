"""The heads-up display: the lines of text and the energy plot, as plain data (no window).

``status_lines`` and ``energy_plot`` are pure functions of the controller and the pacer, so the
wording is tested without Vulkan; ``draw_hud`` lays them out in a ``Batch2D`` for the window.
"""
from __future__ import annotations

import math

import numpy as np

from .canvas2d import Batch2D, text_size
from ..render.overlay import ENERGY_LABEL
from .controller_state import ENERGY_KEYS

# Plot colours (linear RGB): kinetic, spring, gravity, total.
ENERGY_COLORS = {"kinetic_energy": (1.0, 0.55, 0.15), "spring_energy": (0.35, 0.75, 1.0),
                 "gravity_energy": (0.55, 0.90, 0.35), "total_energy": (1.0, 1.0, 1.0)}
ENERGY_LABELS = {"kinetic_energy": "kinetic", "spring_energy": "spring", "gravity_energy": "gravity",
                 "total_energy": "total"}
PLOT_TITLE = "change since t = 0:"  # the plot shows each energy minus its value at the start
TEXT = (0.96, 0.97, 0.98)
ALERT = (1.0, 0.35, 0.30)
PANEL = (0.08, 0.09, 0.12)
# Every key and mouse binding, one line each (the window fits each to its free width).
HELP = ("Space play/pause  N step  R reset+pause  M slow-mo  F O J K L draw  P screenshot  V record  T timing  Esc quit",
        "Left-drag the body: pull  click: poke  Shift+click (or I, pin mode): pin/unpin  X: clear pins  "
        "Right-drag: look  WASD/QE: move  C: camera")


def energy_text(value: float) -> str:
    """An energy [J] in a short fixed-width form: 4 significant digits, scientific when huge."""
    if not math.isfinite(value):
        return "n/a"
    return f"{value:.4g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.1e}"


def pace_text(paused: bool, slow_motion: float, realtime: float, steps_per_second: float, limited: bool) -> str:
    """The pace line: paused, or the real-time factor and, when behind, by how much."""
    if paused:
        return "PAUSED"
    text = f"real time x{realtime:.2f}"
    if slow_motion < 1.0:
        text += f" (slow motion x{slow_motion:g})"
    if limited and realtime > 0:
        text += f", behind: {slow_motion / realtime:.1f}x slower than wanted"
    return f"{text} | {steps_per_second:,.0f} steps/s"


def solver_text(stats: dict) -> str | None:
    """Iterations per step of an implicit method, from ``integrator.stats()``; None if none."""
    parts = []
    for key, label in (("newton_iterations_per_step", "Newton"), ("local_global_iterations_per_step", "local/global"),
                       ("cg_iterations_per_step", "CG"), ("line_search_halvings_per_step", "line search")):
        if key in stats and stats.get("steps", 1):
            parts.append(f"{label} {stats[key]:.1f}")
    return ("iterations per step: " + ", ".join(parts)) if parts else None


def hand_text(controller, hand=None) -> str | None:
    """What the mouse holds: the pulled particle and the spring's stiffness, pins, pin mode."""
    parts = []
    held = controller.grab.held
    if held is not None:
        parts.append(f"pulling particle {held} (k = {controller.settings.grab_stiffness:g} N/m)")
    if controller.pins:
        parts.append(f"{len(controller.pins)} pinned")
    if hand is not None and hand.pin_mode:
        parts.append("PIN MODE: click pins/unpins (I ends)")
    return " | ".join(parts) if parts else None


def status_lines(controller, pacer, stats: dict | None = None) -> list[str]:
    """The HUD's text lines, top to bottom."""
    sim, s = controller.sim, controller.settings
    lines = [f"t = {sim.time:8.3f} s | {sim.integrator_name} | dt = {sim.dt:.3g} s | {sim.terrain.kind}",
             pace_text(s.paused, s.slow_motion, pacer.realtime_factor, pacer.steps_per_second, pacer.limited)]
    m, m0 = controller.last_measures, controller.history.start
    if m is not None and m0 is not None:
        d = {k: m[k] - m0[k] for k in ENERGY_KEYS}
        lines.append(f"{ENERGY_LABEL} = {energy_text(d['total_energy'])} J = kin {energy_text(d['kinetic_energy'])} "
                     f"+ spring {energy_text(d['spring_energy'])} + grav {energy_text(d['gravity_energy'])}")
    solver = solver_text(stats or {})
    if solver:
        lines.append(solver)
    return lines


def energy_plot(history, box) -> list[tuple[str, np.ndarray]]:
    """Polylines of each energy in ``history`` scaled into ``box`` = (x0, y0, x1, y1) pixels.

    All series share one vertical scale (so their sum is visibly the total); time runs left to
    right over the samples kept. Returns [(energy key, points [n, 2])], empty under 2 samples.
    """
    n = len(history.t)
    if n < 2:
        return []
    x0, y0, x1, y1 = box
    values = np.array([history.values[k] for k in ENERGY_KEYS], dtype=np.float64)
    values -= np.array([[history.start[k]] for k in ENERGY_KEYS])  # changes since t = 0
    lo, hi = float(values.min()), float(values.max())
    span = hi - lo if hi > lo else 1.0
    xs = x0 + (x1 - x0) * np.arange(n) / (n - 1)
    return [(k, np.c_[xs, y1 - (y1 - y0) * (values[i] - lo) / span]) for i, k in enumerate(ENERGY_KEYS)]


def draw_hud(batch: Batch2D, controller, pacer, stats: dict | None = None, notice: str | None = None,
             width: int | None = None, hand: str | None = None, extra=()):
    """Lay out the HUD in ``batch``: status top left (then ``hand``, what the mouse holds, and any
    ``extra`` lines), alert, energy plot, help lines; ``width`` [px] is the part of the window left
    free by the control panel (default: all of it)."""
    w, h = width or batch.width, batch.height
    lines = status_lines(controller, pacer, stats) + ([hand] if hand else []) + list(extra)
    alert = controller.message.split("; ") if controller.message else []  # "what happened" / "what to do"
    big = max(12, round(h / 28))  # 29 px in an 800-pixel window: readable from the back of a room
    while big > 12 and max([text_size(t, big)[0] for t in lines] + [text_size(t, big, "bold")[0] for t in alert]) > w - big:
        big -= 1
    small = max(10, round(h / 46))
    y = round(0.4 * big)
    for line in lines:
        batch.text(line, round(0.5 * big), y, big, TEXT)
        y += round(1.25 * big)
    y += round(0.3 * big)
    for line in alert:
        batch.text(line, round(0.5 * big), y, big, ALERT, "bold")
        y += round(1.25 * big)
    if notice:
        batch.text(notice, round(0.5 * big), y + round(0.2 * big), small, TEXT)
    # Energy plot, bottom left, over a dark panel so the lines read against the terrain.
    pad = round(0.5 * small)
    legend_w = sum(text_size(label, small)[0] + 2 * pad for label in (PLOT_TITLE, *ENERGY_LABELS.values()))
    pw, ph = max(round(0.30 * w), legend_w + pad), round(0.20 * h)
    help_size = small
    while help_size > 8 and max(text_size(t, help_size)[0] for t in HELP) > w - 2 * pad:  # fit the free width
        help_size -= 1
    line_h = text_size("Ag", help_size)[1]
    help_h = len(HELP) * line_h + 2 * pad
    px0, py1 = pad, h - help_h - pad
    py0 = py1 - ph
    batch.rect(px0, py0, px0 + pw, py1, PANEL)
    legend_y = py0 + pad
    x = px0 + pad
    batch.text(PLOT_TITLE, x, legend_y, small, TEXT)
    x += text_size(PLOT_TITLE, small)[0] + 2 * pad
    for key in ENERGY_KEYS:
        label = ENERGY_LABELS[key]
        batch.text(label, x, legend_y, small, ENERGY_COLORS[key])
        x += text_size(label, small)[0] + 2 * pad
    top = legend_y + text_size("Ag", small)[1] + pad
    for key, points in energy_plot(controller.history, (px0 + pad, top, px0 + pw - pad, py1 - pad)):
        batch.polyline(points, ENERGY_COLORS[key], width=max(1.5, h / 400))
    batch.rect(0, h - help_h, w, h, PANEL)
    for k, text in enumerate(HELP):
        batch.text(text, pad, h - help_h + pad + k * line_h, help_size, TEXT)
