"""The demo driven by real X input, as a teacher would drive it: every advertised control checked.

    DISPLAY=:1 python -m tests.x11.scripted [--scene plane] [--set body.0.n=3 ...]
                                          [--resolution 1024x640] [--minutes M]

Opens the demo window (started paused) and presses every key the HUD advertises and clicks
panel buttons through the X server (``xinput.XInput``, XTest), checking after each what it did to
the demo's state; screenshots and a recording go to ``out/`` under the working directory. With
``--minutes M`` it then keeps pressing random keys and clicking random buttons for M minutes (a
soak test). Prints one JSON object (``checks``: control -> "ok" or what went wrong; ``actions``:
the soak's counts of keys, clicks, recordings and switches) and exits 0 only if every check passed. Needs an X display (Xvfb will do) in
which the window is the only one, at the top-left corner.

This module holds the command line, the frame-timing measure and the soak; ``driver`` steps the
window and sends the input, ``control_checks`` and ``hand_checks`` hold the checks.
"""
from __future__ import annotations

import argparse
import json
import random
import sys
import time

import numpy as np

from taichi_soft.demo.panel import DRAW_KEYS
from .control_checks import check_every_control, escape_check
from .driver import CAMERA_KEYS, Session
from .hand_checks import check_hands


def measure_timing(s: Session, blocks: int = 4, frames: int = 30) -> dict:
    """The frame timer's breakdown [ms, medians] while playing, alternating blocks of ``frames``
    frames with the body left alone and with its top face's centre grabbed and dragged (the pointer moving
    every frame); also the press frames' input part (picking) and each block's cost per step."""
    ctl, app = s.ctl, s.app
    s.calibrate()
    s.pointer_to_scene()
    if ctl.settings.paused:
        s.press(" ")
    s.frames(10)  # warm: every kernel compiled
    out = {"idle": [], "drag": [], "press_input_ms": []}
    for b in range(2 * blocks):
        mode = "idle" if b % 2 == 0 else "drag"
        if mode == "drag":
            x = s.positions()
            top = int(np.argmin(np.linalg.norm(x - [x[:, 0].mean(), x[:, 1].max(), x[:, 2].mean()], axis=1)))
            px, py = s.pixel(x[top])  # the top face's centre: well inside the silhouette
            s.move(px, py)
            s.frames(1)
            s.x.button("LMB", True)
            assert s.until(lambda: ctl.grab.held is not None), "the press grabbed nothing"
            out["press_input_ms"].append(1e3 * app.timer.frames[-1].get("input", 0.0))
        app.timer.frames.clear()
        steps0 = ctl.sim.steps
        for k in range(frames):
            if mode == "drag":
                s.move(px + (k % 10) * 3, py - 3 * k)
            s.frames(1)
        m = app.timer.medians_ms()
        m["ms_per_step"] = m["simulation"] * frames / max(ctl.sim.steps - steps0, 1)
        out[mode].append(m)
        if mode == "drag":
            s.x.button("LMB", False)
            s.frames(2)
    summary = {mode: {k: float(np.median([m[k] for m in out[mode]])) for k in out[mode][0]} for mode in ("idle", "drag")}
    summary["press_input_ms"] = out["press_input_ms"]
    return summary


def soak(s: Session, minutes: float, seed: int = 0) -> dict:
    """Random keys and button clicks for ``minutes``; returns how many of each kind were done
    (``keys``, ``clicks``, ``recordings`` toggled, and the ``integrators`` and ``terrains``
    switched to).

    Raises if the window closes or the state stops being finite without a divergence message.
    """
    rng = random.Random(seed)
    keys = [" ", "n", "r", "m", "c", "p", *DRAW_KEYS, *CAMERA_KEYS]
    end = time.monotonic() + 60 * minutes
    done = {"keys": 0, "clicks": 0, "recordings": 0, "integrators": 0, "terrains": 0}
    bands = s.buttons()
    while time.monotonic() < end:
        roll = rng.random()
        before = (s.ctl.settings.integrator, s.ctl.settings.terrain)
        if roll < 0.55:
            s.press(rng.choice(keys), frames=rng.randint(1, 5))
            done["keys"] += 1
        elif roll < 0.9:
            # Any button but the last (recording: toggled below, rarely, so files stay small).
            s.click(rng.choice(bands[:-1]), frames=rng.randint(1, 5))
            bands = s.buttons()  # a terrain switch or a label change may move them
            done["clicks"] += 1
        else:
            s.press("v", frames=rng.randint(5, 20))
            done["recordings"] += 1
        done["integrators"] += s.ctl.settings.integrator != before[0]
        done["terrains"] += s.ctl.settings.terrain != before[1]
        if not s.app.window.running:
            raise AssertionError(f"the window closed after {done}")
        m = s.ctl.last_measures
        if m is not None and not s.ctl.message:
            assert np.isfinite(m["total_energy"]), "non-finite energy without a divergence message"
    if s.app.recording is not None:
        s.press("v")
    return done


def main(argv=None) -> int:
    from taichi_soft.runtime import init
    from taichi_soft.sim.scene_validation import parse_resolution
    from taichi_soft.demo.app import DemoApp
    from taichi_soft.demo.controller import DemoController
    from taichi_soft.demo.display import open_demo_window
    from .xinput import XInput

    p = argparse.ArgumentParser(prog="python -m tests.x11.scripted", description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="plane")
    p.add_argument("--set", action="append", default=[])
    p.add_argument("--resolution", default="1024x640")
    p.add_argument("--minutes", type=float, default=0.0, help="soak test length after the checks")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--hands", action="store_true",
                   help="check the mouse on the body (pins, drag, poke, yank) instead of the keys and buttons")
    p.add_argument("--yank", default="explicit_euler:0.002:1e5", metavar="INTEGRATOR:DT:K",
                   help="--hands: the hard yank's integrator, dt [s] and grab stiffness [N/m]")
    p.add_argument("--record", metavar="SESSION.json", help="record the session's inputs (as demo --record)")
    p.add_argument("--timing", action="store_true",
                   help="measure the frame timer's breakdown idle and while dragging; print it and exit")
    args = p.parse_args(argv)
    size = parse_resolution(args.resolution)
    init("cpu", "f64")
    window = open_demo_window("taichi-soft demo", size, fps_limit=1000)
    app = DemoApp(DemoController(args.scene, args.set, "semi_implicit_euler", paused=True), size, window)
    if args.record:
        from taichi_soft.demo.app import start_session

        start_session(app, args.record)
    xin = XInput()
    session = Session(app, xin)
    report = {"checks": {}, "actions": {}}
    try:
        if args.timing:
            report["timing"] = measure_timing(session)
            escape = escape_check(session)
        elif args.hands:
            name, dt, k = args.yank.split(":")
            report["checks"], report["actions"] = check_hands(session, name, float(dt), float(k))
            escape = escape_check(session)
        else:
            report["checks"], escape = check_every_control(session)
        if args.minutes > 0 and app.window.running:
            try:
                report["actions"] = soak(session, args.minutes, args.seed)
                report["checks"]["soak"] = "ok"
            except Exception as e:  # noqa: BLE001
                report["checks"]["soak"] = f"{type(e).__name__}: {e}".splitlines()[0]
        if app.window.running:
            try:
                escape()
                report["checks"]["Esc quits"] = "ok"
            except Exception as e:  # noqa: BLE001
                report["checks"]["Esc quits"] = f"{type(e).__name__}: {e}".splitlines()[0]
    finally:
        if app.recording is not None:
            app.toggle_recording()
        app.close_session()
        app.window.destroy()
        xin.close()
    report["final"] = {"time": app.ctl.sim.time, "steps": app.ctl.sim.steps}
    print(json.dumps(report))
    return 0 if all(v == "ok" for v in report["checks"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
