"""What the demo controller keeps beside its simulation: the ``Settings`` the controls show and
set, and the ``EnergyHistory`` of recent energies the HUD plots.
"""
from __future__ import annotations

from dataclasses import dataclass, field

HISTORY = 240  # energy samples kept for the HUD plot (one per frame that stepped: a few seconds)
ENERGY_KEYS = ("kinetic_energy", "spring_energy", "gravity_energy", "total_energy")


@dataclass
class Settings:
    """The values the controls show and set. Units: SI (s, N/m, N s/m, kg, m, degrees, m/s^2)."""

    integrator: str
    terrain: str
    dt: float
    stiffness: dict  # spring kind -> k [N/m] (applied to every body)
    damping: float  # damper coefficient [N s/m] of every spring kind and body
    restitution: float  # [0, 1]
    friction: float  # Coulomb coefficient >= 0
    particle_mass: float  # [kg], every particle
    height: float  # height [m] of the first body's centre at reset
    rotation: float  # first body's rotation [degrees] about its scene axis at reset
    gravity: float  # magnitude [m/s^2] along the scene's gravity direction
    paused: bool = False
    slow_motion: float = 1.0  # simulated seconds per wall-clock second wanted (1 = real time)
    duration: float | None = None  # [s] simulated time after which the demo stops (None: runs on)
    grab_stiffness: float = 1000.0  # [N/m] of the spring pulling a grabbed particle to the cursor
    poke_speed: float = 3.0  # [m/s] velocity a poke adds to the poked particle


@dataclass
class EnergyHistory:
    """Recent energy samples [J] for the HUD plot: ``t`` [s] and one list per ``ENERGY_KEYS``."""

    t: list = field(default_factory=list)
    values: dict = field(default_factory=lambda: {k: [] for k in ENERGY_KEYS})
    # The energies of the first sample since the last clear (the start, t = 0): the HUD shows
    # changes from them, which do not depend on where gravity's zero is.
    start: dict | None = None

    def add(self, time: float, measures: dict):
        """Append a sample at simulated ``time`` [s]; a sample at the time already last is not
        added again (a paused demo keeps the history it had when paused)."""
        if self.t and self.t[-1] == time:
            return
        if self.start is None:
            self.start = {k: measures[k] for k in ENERGY_KEYS}
        self.t.append(time)
        for k in ENERGY_KEYS:
            self.values[k].append(measures[k])
        if len(self.t) > HISTORY:
            del self.t[0]
            for k in ENERGY_KEYS:
                del self.values[k][0]

    def clear(self):
        self.start = None
        self.t.clear()
        for k in ENERGY_KEYS:
            self.values[k].clear()
