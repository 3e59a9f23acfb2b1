"""What the demo's controls do to the simulation: plain Python, no window, driven by tests.

``DemoController`` owns one ``Simulation`` and applies every control through the engine's public
run-time parameters (fields and kernel arguments), so a slider never triggers a recompile:

* integrator: switched live, continuing from the current state. Each integrator is built once
  per terrain and kept (building one compiles its kernels, 1-7 s on a CPU);
* terrain: a ``Simulation`` of the same scene with ``terrain.kind`` overridden (its kernels are
  compiled for that shape only, see ``taichi_soft.sim.contact.terrain``), built on the first switch to that
  terrain and kept, with its integrators, for every later one: a class flicking between terrains
  compiles each once and never runs out of Taichi field trees (``sim.allocation``). Every current
  setting is carried over and the cube starts again from its initial state;
* dt, stiffness, damping, restitution, friction, particle mass, gravity: live, next step;
* drop height and rotation: change the initial pose, applied on ``reset()``;
* the hand (``grab.py``): ``grab`` a particle toward a point, ``drag`` the point, ``release``;
  ``poke`` a particle (a velocity kick); ``toggle_pin`` / ``clear_pins`` (a pinned particle has
  inverse mass 0 and stays where it is). Pins are kept across integrator and terrain switches;
  ``reset`` clears them and lets go of the grab.

Every method that changes the simulation is an *input* (``@recorded``): with a ``recorder`` set
(``session.SessionRecorder``), each outermost call is logged with its arguments, so a session
replays call for call, steps included (``step(n)`` is an input too).

A step that diverges, or any error the engine raises while stepping, pauses the simulation and
leaves a one-line ``message``; ``reset()`` clears it. The controller never raises from a step.

This module holds the controller's construction, choices (integrator, terrain) and running; the
live parameters and the hand are its mixins in ``live_controls``, its settings and energy history
in ``controller_state``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import UserError
from ..sim.grab import attach as attach_grab
from ..sim.integrators import REGISTRY, make_integrator, scene_options
from ..sim.lattice import SPRING_KINDS, rotation_matrix
from ..sim.scene import load_scene
from ..sim.simulation import Simulation
from ..sim.contact.terrain import KINDS as TERRAIN_KINDS
from .controller_state import ENERGY_KEYS, EnergyHistory, Settings
from .live_controls import HandControls, LiveParameters, recorded


@dataclass
class _Built:
    """A simulation built for one terrain and what belongs to it: its grab, the integrators built on
    it so far (by name), and the scene's own pose [m] before the window's height and rotation."""

    sim: Simulation
    grab: object
    scene_x0: np.ndarray
    integrators: dict = field(default_factory=dict)


class DemoController(LiveParameters, HandControls):
    """The simulation behind the demo window and every control applied to it.

    ``scene`` is a scene name or path, ``overrides`` ``--set`` style assignments; ``integrator``
    and ``dt`` [s] override the scene's. Taichi must be initialised first.
    """

    def __init__(self, scene: str = "plane", overrides=(), integrator: str | None = None, dt: float | None = None,
                 paused: bool = False, duration: float | None = None):
        self.scene_name = scene
        self.overrides = list(overrides)
        base = self._load(self.overrides)
        body = base.data["body"][0]
        gravity = np.asarray(base.sim["gravity"], dtype=np.float64)
        g = float(np.linalg.norm(gravity))
        # Gravity is scaled along the scene's direction; a weightless scene gets "down" (-y).
        self._g_dir = gravity / g if g > 0 else np.array([0.0, -1.0, 0.0])
        self.settings = Settings(
            integrator=integrator or base.sim["integrator"], terrain=base.data["terrain"]["kind"],
            dt=float(dt if dt is not None else base.sim["dt"]),
            stiffness={kind: float(body[kind]["k"]) for kind in SPRING_KINDS},
            damping=float(body["stretch"]["damping"]), restitution=float(base.data["contact"]["restitution"]),
            friction=float(base.data["contact"]["friction"]), particle_mass=float(body["particle_mass"]),
            height=float(body["center"][1]), rotation=float(body["rotation"]["degrees"]), gravity=g, paused=paused,
            duration=duration)
        if self.settings.integrator not in REGISTRY:
            raise UserError(f"unknown integrator {self.settings.integrator!r}; choose one of: {', '.join(REGISTRY)}")
        self.message: str | None = None  # why the simulation stopped (divergence or error)
        self.history = EnergyHistory()
        self.last_measures: dict | None = None
        self.generation = 0  # bumped whenever ``sim`` is replaced (views must be rebuilt)
        self.pins: set[int] = set()  # pinned particle indices (inverse mass 0)
        self.recorder = None  # set by a recording session: logs every input (``recorded``)
        self._depth = 0  # nesting of input calls (only the outermost is logged)
        self._built: dict[str, _Built] = {}  # by terrain kind
        self._activate(self._build(base))

    # -- construction -----------------------------------------------------------------------
    def _load(self, overrides):
        from ..sim.integrators import names

        return load_scene(self.scene_name, overrides, integrator_names=names())

    def _build(self, scene) -> _Built:
        """A new ``Simulation`` for ``scene`` with the current integrator and dt, kept by terrain."""
        s = self.settings
        # The window places the body itself (height, rotation: set_pose), so the scene's own start
        # is not checked against the terrain here.
        sim = Simulation(scene, integrator=s.integrator, dt=s.dt, options=scene_options(s.integrator, scene.data),
                         check=False)
        grab = attach_grab(sim.model)  # before any step compiles: the steps include its force
        built = _Built(sim, grab, sim.model.x0_np.copy(), {s.integrator: sim.integrator})
        self._built[sim.terrain.kind] = built
        return built

    def _activate(self, built: _Built):
        """Make ``built`` the running simulation with every current setting applied, at its start."""
        self.sim, self.grab = built.sim, built.grab
        self._integrators = built.integrators
        self._scene_x0 = built.scene_x0
        self._mass_applied = None
        self.generation += 1
        self._use_integrator(self.settings.integrator)
        self.sim.set_dt(self.settings.dt)
        self._apply_live_settings()
        self.reset()

    def _apply_live_settings(self):
        s = self.settings
        for kind, k in s.stiffness.items():
            self.set_stiffness(kind, k)
        self.set_damping(s.damping)
        self.set_contact(s.restitution, s.friction)
        self.set_particle_mass(s.particle_mass)
        self.set_gravity(s.gravity)
        self.set_grab_stiffness(s.grab_stiffness)

    # -- choices ----------------------------------------------------------------------------
    @staticmethod
    def integrator_names() -> list[str]:
        return list(REGISTRY)

    @staticmethod
    def terrain_kinds() -> list[str]:
        return list(TERRAIN_KINDS)

    @recorded
    def set_integrator(self, name: str):
        """Continue from the current state with integrator ``name`` (from the start if diverged)."""
        if name == self.sim.integrator_name:
            return
        self._use_integrator(name)
        self.settings.integrator = name
        if self.sim.diverged or self.message:
            self.reset()

    def _use_integrator(self, name: str):
        """Switch the running simulation to integrator ``name``, built once per terrain."""
        if name == self.sim.integrator_name:
            return
        integ = self._integrators.get(name)
        if integ is None:
            integ = make_integrator(name, self.sim.model, self.sim.terrain, scene_options(name, self.sim.scene.data),
                                    self.sim.contacts)
            self._integrators[name] = integ
        self.sim.set_integrator(integ)

    @recorded
    def set_terrain(self, kind: str):
        """Continue on terrain ``kind`` (its default geometry) with the same settings, from the start;
        the simulation for ``kind`` is built on the first switch to it and kept."""
        if kind == self.sim.terrain.kind:
            return
        built = self._built.get(kind)
        if built is None:
            built = self._build(self._load(self.overrides + [f"terrain.kind={kind}"]))
        pins = sorted(self.pins)
        self.grab.release()  # the simulation left behind keeps no hand and no pins
        self.clear_pins()
        self._activate(built)
        self.settings.terrain = kind
        for i in pins:  # the same particles, pinned where the new start puts them
            self.toggle_pin(i)

    # -- running ----------------------------------------------------------------------------
    @recorded
    def toggle_pause(self):
        self.settings.paused = not self.settings.paused

    @recorded
    def restart(self):
        """What R does: back to the start (``reset``) and paused, so the class can predict what
        happens before Space plays it."""
        self.reset()
        self.settings.paused = True

    @recorded
    def reset(self):
        """Back to the initial state with the current height and rotation; clears a divergence
        (and the pause it caused)."""
        if self.message:
            self.settings.paused = False
        self.grab.release()
        if self.pins:
            self.sim.model.set_masses(sorted(self.pins), self.settings.particle_mass)
            self.pins.clear()
        model = self.sim.model
        model.x0_np, model.v0_np = self._initial_pose()
        self.sim.reset()
        self.message = None
        self.history.clear()
        self.last_measures = None
        self.sample()

    def _initial_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Initial positions [m] and velocities [m/s]: the scene's pose moved up by the height
        change and turned about each body's rotation axis by the rotation change."""
        s = self.settings
        scene_bodies = self.sim.scene.data["body"]
        dy = s.height - scene_bodies[0]["center"][1]
        dturn = s.rotation - scene_bodies[0]["rotation"]["degrees"]
        x0 = self._scene_x0.copy()
        v0 = np.empty_like(x0)
        for info, body in zip(self.sim.model.bodies, scene_bodies):
            c = np.asarray(body["center"], dtype=np.float64)
            turn = rotation_matrix(body["rotation"]["axis"], dturn)
            local = (x0[info.particles] - c) @ turn.T
            x0[info.particles] = local + c + [0.0, dy, 0.0]
            v0[info.particles] = np.asarray(body["velocity"]) + np.cross(body["angular_velocity"], local)
        return x0, v0

    @recorded
    def step(self, n: int = 1) -> int:
        """Take up to ``n`` steps now (even while paused); returns the steps taken.

        Divergence or an engine error pauses the simulation and sets ``message``.
        """
        if self.message or n <= 0:
            return 0
        end = self.settings.duration
        if end is not None:  # --duration: stop there, as `run` does (R restarts)
            n = min(n, math.floor((end - self.sim.time) / self.sim.dt + 1e-9))
            if n <= 0:
                self._stop(f"stopped at t = {self.sim.time:.3f} s, the end of --duration {end:g} s; R restarts")
                return 0
        try:
            done = self.sim.advance(int(n))
        except Exception as e:  # noqa: BLE001 - the window must survive any engine error
            self._stop(f"stopped: {type(e).__name__}: {e}".splitlines()[0])
            return 0
        if self.sim.diverged:
            s = self.sim
            self._stop(f"diverged at t = {s.diverged_at:.4f} s with {s.integrator_name} at dt = {s.dt:g} s; "
                       f"try dt <= {s.suggest_dt():g} (R resets)")
        return done

    @recorded
    def single_step(self):
        """What N does: pause and take one step."""
        self.settings.paused = True
        self.step(1)


    def _stop(self, message: str):
        self.message = message
        self.settings.paused = True

    def sample(self) -> dict | None:
        """Measure the current state and append its energies to ``history`` (once per simulated
        time: sampling a paused simulation adds nothing).

        After a divergence the state holds NaN: the last good measures are kept instead.
        """
        if self.message:
            return self.last_measures
        m = self.sim.measure()
        if not all(math.isfinite(m[k]) for k in ENERGY_KEYS):
            return self.last_measures
        self.last_measures = m
        self.history.add(self.sim.time, m)
        return m

    def solver_stats(self) -> dict:
        """The current integrator's iteration counts since the last call (implicit methods)."""
        return self.sim.integrator.stats() if self.sim.integrator.implicit else {}
