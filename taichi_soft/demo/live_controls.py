"""The demo's controls that act on the running simulation without rebuilding it, as mixins of
``DemoController``: ``LiveParameters`` (dt, stiffness, damping, restitution, friction, particle
mass, gravity: next step; drop height and rotation: at ``reset()``; slow motion) and ``HandControls``
(grab, drag, release, poke, pins). Each is an input (``@recorded``, see ``controller``): with a
``recorder`` set, each outermost call is logged with its arguments.
"""
from __future__ import annotations

import functools

import numpy as np

from ..sim.lattice import SPRING_KINDS


def recorded(method):
    """Mark a ``DemoController`` method as an input: its outermost calls go to ``recorder``."""

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        outer = self._depth == 0
        self._depth += 1
        try:
            result = method(self, *args, **kwargs)
        finally:
            self._depth -= 1
        if outer and self.recorder is not None:
            self.recorder.input(method.__name__, list(args), kwargs)
        return result

    wrapper.recorded = True
    return wrapper


class LiveParameters:
    """dt, springs, contact, mass, gravity, start pose and slow motion of a ``DemoController``."""

    @recorded
    def set_dt(self, dt: float):
        """Time step [s] from the next step on."""
        self.settings.dt = float(dt)
        self.sim.set_dt(dt)

    @recorded
    def set_stiffness(self, kind: str, k: float):
        """Stiffness [N/m] of spring ``kind`` in every body."""
        self.settings.stiffness[kind] = float(k)
        for b in range(len(self.sim.model.bodies)):
            self.sim.model.set_spring_params(b, kind, k=float(k))

    @recorded
    def set_damping(self, damping: float):
        """Damper coefficient [N s/m] of every spring kind in every body."""
        self.settings.damping = float(damping)
        for b in range(len(self.sim.model.bodies)):
            for kind in SPRING_KINDS:
                self.sim.model.set_spring_params(b, kind, damping=float(damping))

    @recorded
    def set_contact(self, restitution: float | None = None, friction: float | None = None):
        """Restitution [0, 1] and Coulomb friction coefficient of the terrain contact."""
        if restitution is not None:
            self.settings.restitution = float(restitution)
        if friction is not None:
            self.settings.friction = float(friction)
        # Both coefficients in one write whichever moved: ``assign`` compiles one kernel per set of
        # fields it writes, so a slider moving one alone would compile a second writer on its first move.
        self.sim.terrain.set_contact(restitution=self.settings.restitution, friction=self.settings.friction)

    @recorded
    def set_particle_mass(self, mass: float):
        """Mass [kg] of every particle (pinned particles, inverse mass 0, stay pinned)."""
        self.settings.particle_mass = float(mass)
        if self._mass_applied == mass:
            return
        self.sim.model.set_particle_mass(float(mass))
        self._mass_applied = mass
        self.grab.set_stiffness(self.settings.grab_stiffness)  # its damper follows the mass

    @recorded
    def set_gravity(self, magnitude: float):
        """Gravity [m/s^2] along the scene's direction (straight down for a weightless scene)."""
        self.settings.gravity = float(magnitude)
        self.sim.model.set_gravity(self._g_dir * float(magnitude))

    @recorded
    def set_pose(self, height: float | None = None, rotation: float | None = None):
        """Drop height [m] and rotation [degrees] of the first body; take effect at ``reset()``."""
        if height is not None:
            self.settings.height = float(height)
        if rotation is not None:
            self.settings.rotation = float(rotation)

    @recorded
    def set_slow_motion(self, factor: float):
        """Simulated seconds per wall-clock second wanted, in (0, 1]."""
        self.settings.slow_motion = min(max(float(factor), 1e-3), 1.0)



class HandControls:
    """The mouse's hand on the body of a ``DemoController``: grab, drag, release, poke, pins."""

    @recorded
    def set_grab_stiffness(self, k: float):
        """Stiffness [N/m] of the spring that pulls a grabbed particle toward the cursor (its damper
        critically damps the particle alone on it, ``Grab.set_stiffness``)."""
        self.settings.grab_stiffness = float(k)
        self.grab.set_stiffness(float(k))

    @recorded
    def set_poke_speed(self, speed: float):
        """Speed [m/s] a poke adds to the poked particle."""
        self.settings.poke_speed = float(speed)

    @recorded
    def grab_particle(self, i: int, target):
        """Pull particle ``i`` toward ``target`` [m] from the next step on (a pinned one stays put)."""
        self.grab.hold(int(i), target)

    @recorded
    def drag(self, target):
        """Move the grabbed particle's target [m]."""
        self.grab.move(target)

    @recorded
    def release(self):
        self.grab.release()

    @recorded
    def poke(self, i: int, direction):
        """Add ``poke_speed`` [m/s] along ``direction`` (any length) to particle ``i``'s velocity."""
        d = np.asarray(direction, dtype=np.float64)
        norm = float(np.linalg.norm(d))
        if norm == 0 or int(i) in self.pins or self.message:
            return
        v = self.sim.state.v
        v[int(i)] = tuple(np.asarray(v[int(i)].to_numpy(), dtype=np.float64) + self.settings.poke_speed * d / norm)

    @recorded
    def toggle_pin(self, i: int):
        """Pin particle ``i`` where it is (inverse mass 0, at rest), or unpin it if pinned."""
        i = int(i)
        model = self.sim.model
        if i in self.pins:
            self.pins.discard(i)
            model.set_masses([i], self.settings.particle_mass)
        else:
            self.pins.add(i)
            model.set_masses([i], 0.0)
            self.sim.state.v[i] = (0.0, 0.0, 0.0)

    @recorded
    def clear_pins(self):
        """Unpin every pinned particle (they fall with the rest)."""
        if self.pins:
            self.sim.model.set_masses(sorted(self.pins), self.settings.particle_mass)
            self.pins.clear()
