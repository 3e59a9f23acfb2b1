"""The checks of the mouse on the body, through real X input (``scripted --hands``): pins, a
drag, a poke and a hard yank.
"""
from __future__ import annotations

import numpy as np

from .driver import Session, run_checks


def top_corners(s: Session) -> list[int]:
    """The body's four top corners (the 8 particles farthest from its centre, the 4 highest),
    nearest the camera first."""
    x = s.positions()
    c = x.mean(axis=0)
    corners = np.argsort(-np.linalg.norm(x - c, axis=1))[:8]
    top = corners[np.argsort(-x[corners, 1])[:4]]
    eye = np.asarray(s.app.cam_spec.position)
    return [int(i) for i in top[np.argsort(np.linalg.norm(x[top] - eye, axis=1))]]


def check_hands(s: Session, yank_integrator: str = "explicit_euler", yank_dt: float = 2e-3,
                yank_k: float = 1e5) -> tuple[dict, dict]:
    """The mouse on the body, through real X input: pin two top corners and let it hang, clear the
    pins, drag a top corner up and let go, poke, and a hard yank with ``yank_integrator`` at
    ``yank_dt`` [s] and grab stiffness ``yank_k`` [N/m]. The scene must start with the body in the
    air above the floor, paused. Returns (check -> "ok" or the failure, {"yank": "held" or
    "diverged, reset"})."""
    ctl, app = s.ctl, s.app
    s.calibrate()
    s.pointer_to_scene()
    s.frames(3)

    def click_particle(i, shift=False):
        s.move(*s.pixel(s.positions()[i]))
        s.frames(1)
        if shift:
            s.x.key("Shift", True)
            s.frames(1)
        s.x.button("LMB", True)
        s.frames(1)
        s.x.button("LMB", False)
        s.frames(1)
        if shift:
            s.x.key("Shift", False)
            s.frames(1)

    def pins_hold_and_hang():
        assert ctl.settings.paused and ctl.sim.time == 0.0, "the session must start paused"
        a, b = top_corners(s)[:2]
        click_particle(a, shift=True)
        s.until(lambda: len(ctl.pins) == 1)
        click_particle(b, shift=True)
        s.until(lambda: len(ctl.pins) == 2)
        assert ctl.pins == {a, b}, f"Shift+click pinned {sorted(ctl.pins)}, not the corners {a}, {b}"
        assert ctl.sim.time == 0.0, "pinning stepped the simulation"
        x0 = s.positions()
        s.press(" ")
        s.run_for(2.0)
        assert ctl.message is None, ctl.message
        x = s.positions()
        moved = float(np.abs(x[[a, b]] - x0[[a, b]]).max())
        assert moved <= 1e-9, f"the pinned corners moved {moved:.3g} m"
        free = np.setdiff1d(np.arange(len(x)), [a, b])
        pin_y = x0[[a, b], 1].mean()
        assert x[free, 1].mean() < pin_y - 0.2, "the body does not hang below its pins"
        # hanging, not fallen: the free particles stay within the body's reach of the pins
        assert x[free, 1].min() > pin_y - 2.5 * np.ptp(x0[:, 1]) - 0.5, "the body fell away from its pins"
        s.pins_y = pin_y

    def x_clears_pins_and_it_falls():
        com0 = s.positions()[:, 1].mean()
        s.press("x")
        assert not ctl.pins, f"X left pins {sorted(ctl.pins)}"
        s.run_for(0.3)
        assert s.positions()[:, 1].mean() < com0 - 0.1, "after X the body did not fall"
        s.run_for(2.0)  # lands and settles for the drag

    def reset_clears_pins():
        click_particle(top_corners(s)[0], shift=True)
        assert s.until(lambda: len(ctl.pins) == 1), ctl.pins
        s.press("r")
        assert not ctl.pins and ctl.sim.time == 0.0, (ctl.pins, ctl.sim.time)
        s.press(" ")
        s.run_for(2.5)  # falls, lands, settles

    def drag_up_and_release():
        corner = top_corners(s)[0]
        x0 = s.positions()
        px, py = s.pixel(x0[corner])
        s.move(px, py)
        s.frames(1)
        s.x.button("LMB", True)
        s.until(lambda: ctl.grab.held is not None)
        assert ctl.grab.held == corner, f"the press grabbed {ctl.grab.held}, not the corner {corner}"
        start = ctl.sim.time
        s.run_for(1.0, during=lambda k: s.move(px, py - min(150, 15 * (k + 1))))
        x1 = s.positions()
        target = ctl.grab.target.to_numpy()
        assert target[1] > x0[corner, 1] + 0.3, f"150 px up put the target only at {target}"
        assert x1[corner, 1] > x0[corner, 1] + 0.2, f"the corner rose only {x1[corner, 1] - x0[corner, 1]:.3f} m"
        others = np.setdiff1d(np.arange(len(x1)), [corner])
        assert x1[others, 1].mean() > x0[others, 1].mean() + 0.05, "the body did not follow the corner"
        assert ctl.sim.time >= start + 1.0
        s.x.button("LMB", False)
        assert s.until(lambda: ctl.grab.held is None), "release did not let go"
        s.run_for(1.5)
        x2 = s.positions()
        assert x2[corner, 1] < x1[corner, 1] - 0.15, "the corner did not fall back"
        assert abs(x2[:, 1].mean() - x0[:, 1].mean()) < 0.1, "the body did not come back to rest on the floor"

    def click_pokes():
        corner = top_corners(s)[0]
        s.press(" ")  # pause: the kick is read before any step damps it
        assert ctl.settings.paused
        v0 = ctl.sim.state.v.to_numpy()[corner].astype(float)
        eye = np.asarray(app.cam_spec.position)
        click_particle(corner)
        s.until(lambda: np.any(ctl.sim.state.v.to_numpy()[corner] != v0) and ctl.grab.held is None)
        dv = ctl.sim.state.v.to_numpy()[corner] - v0
        ray = s.positions()[corner] - eye
        ray /= np.linalg.norm(ray)
        speed = ctl.settings.poke_speed
        assert abs(np.linalg.norm(dv) - speed) < 1e-6 * speed, f"the poke added {np.linalg.norm(dv)} m/s, not {speed}"
        assert dv @ ray > 0.99 * speed, "the poke is not along the view ray"
        assert ctl.grab.held is None
        s.press(" ")
        s.run_for(0.5)

    def hard_yank():
        ctl.set_integrator(yank_integrator)  # set up as the panel would: integrator, dt, grab k
        ctl.set_dt(yank_dt)
        ctl.set_grab_stiffness(yank_k)
        corner = top_corners(s)[0]
        px, py = s.pixel(s.positions()[corner])
        s.move(px, py)
        s.frames(1)
        s.x.button("LMB", True)
        assert s.until(lambda: ctl.grab.held is not None), "the press grabbed nothing"
        s.move(px, max(py - 300, 5))
        s.run_for(1.0)
        s.x.button("LMB", False)
        s.frames(2)
        assert app.window.running, "the window closed"
        if ctl.message:  # diverged: the demo says so and R recovers
            assert ctl.message.startswith("diverged") and "R resets" in ctl.message, ctl.message
            s.press("r")
            assert ctl.message is None and ctl.sim.time == 0.0
            s.press(" ")
            s.run_for(0.2)
            assert np.isfinite(s.positions()).all()
            s.result = "diverged, reset"
        else:
            assert np.isfinite(s.positions()).all(), "non-finite state without a divergence message"
            s.result = "held"

    checks = (("Shift+click pins two corners, it hangs", pins_hold_and_hang),
              ("X clears the pins, it falls", x_clears_pins_and_it_falls),
              ("R clears pins", reset_clears_pins),
              ("drag a top corner up, release", drag_up_and_release),
              ("click pokes", click_pokes),
              (f"hard yank with {yank_integrator} at dt {yank_dt:g} s", hard_yank))
    return run_checks(app, checks), {"yank": getattr(s, "result", None)}
