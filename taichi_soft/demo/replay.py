"""``demo --replay``: a recorded session (``session``) played back without a display into a video.

Apart from ``session`` (which the live demo imports to record) because playing back needs the
whole demo window (``app``): one direction of import each, no circle.
"""
from pathlib import Path

import numpy as np


def replay(data: dict, video: Path, window=None) -> dict:
    """Play a loaded session back in a hidden window into ``video`` (MP4 or GIF, committed whole);
    returns {"frames", "time", "steps", "max_deviation_m"} (the largest distance [m] between the
    replayed and the recorded final positions; None if the file has none)."""
    from ..render.window import open_window
    from .app import DemoApp
    from .capture import Recording
    from .controller import DemoController
    from .pacing import Pacer

    setup = data["setup"]
    size = tuple(setup["resolution"])
    window = window or open_window(size[0], size[1], "taichi-soft replay", visible=False)
    ctl = DemoController(setup["scene"], setup.get("overrides", []), setup.get("integrator"), setup.get("dt"),
                         paused=bool(setup.get("paused")), duration=setup.get("duration"))
    app = DemoApp(ctl, size, window)
    now = [0.0]
    app.pacer = Pacer(clock=lambda: now[0])  # the HUD's pace line in the live session's time
    recording = Recording(video, size, clock=lambda: now[0])
    try:
        for frame in data["frames"]:
            steps = 0
            for name, args, kwargs in frame.get("ops", []):
                done = getattr(ctl, name)(*args, **kwargs)
                steps += done if name == "step" else 0
            if "draw" in frame:
                app.draw.update(frame["draw"])
            if "camera" in frame:
                now[0] = float(frame["t"])
                app.pacer.record(steps, 0.0, ctl.sim.dt)
                app.replay_frame(frame["camera"])
                recording.add(window)
        path = recording.stop()
    except BaseException:
        recording.video.abort()
        raise
    finally:
        window.destroy()
    final = data.get("final") or {}
    deviation = None
    if final.get("x") is not None:
        x = ctl.sim.state.x.to_numpy().astype(np.float64)
        want = np.asarray(final["x"], dtype=np.float64)
        deviation = float("inf")
        # A session that diverged ends with non-finite positions: those must match where they are.
        if want.shape == x.shape and np.array_equal(np.isfinite(x), np.isfinite(want)):
            both = np.isfinite(x)
            deviation = float(np.abs(x[both] - want[both]).max(initial=0.0))
    return {"video": str(path), "frames": len(data["frames"]), "time": ctl.sim.time, "steps": ctl.sim.steps,
            "max_deviation_m": deviation}
