"""The integrator interface every method implements, and the kernels that launch its steps.

An integrator advances a ``State`` in place: ``advance(state, dt, n_steps) -> steps_done``.
Explicit methods only write ``_step_body(x, v, dt)``, a ``ti.func`` made of loops over
particles; this base class runs it two ways from the same source:

* serial: one kernel launch runs many steps on one thread. On a CPU each parallel launch costs
  about 0.1 ms however small the loop, so small bodies (a 1000-particle cube) run several times
  faster this way;
* parallel: one launch per step, each particle loop spread over all cores (or GPU threads).

Every step ends with ``_finish`` per particle: the terrain's collision response (projection and
restitution, the same for every method) and the divergence check (any non-finite velocity or
|v|^2 > limit); then, in scenes with several bodies, the body-body contact pass
(``self.contacts``, set by ``Simulation`` before the first step; None compiles no contact code). A diverged step stops a serial run at that step; parallel runs record the
first diverged step index.
"""

import taichi as ti

from ..errors import UserError
from ..forces import ForceEvaluator

# Parallel launches win above this many particles on a CPU (measured: see docs/benchmarks).
SERIAL_MAX_PARTICLES = 4096
NOT_DIVERGED = 2**31 - 1


@ti.data_oriented
class Integrator:
    """Base class. Subclasses set ``name``, ``order``, ``force_evals`` and ``_step_body(x, v, dt, step)``."""

    name = "base"
    order = 0  # global order of accuracy in dt (smooth problems)
    force_evals = 0  # force evaluations per step
    implicit = False
    description = ""
    # Options a scene's [solver] table (or --set solver.NAME=VALUE) may set:
    # name -> (default, check(value) -> bool, what is allowed). Subclasses extend it.
    OPTIONS = {
        "mode": ("auto", lambda v: v in ("auto", "serial", "parallel"),
                 "auto, serial (many steps per launch on one thread) or parallel (one launch per step)"),
    }

    def __init__(self, model, terrain, options: dict | None = None):
        self.model = model
        self.terrain = terrain
        self.n = model.n_particles
        self.options = self.parse_options(options or {})
        self.speed2_limit = ti.field(float, ())  # divergence threshold on |v|^2 [m^2/s^2]
        self.speed2_limit[None] = 1e6
        self.diverged_step = ti.field(ti.i32, ())
        self.diverged_step[None] = NOT_DIVERGED
        self.mode = self.options["mode"]
        self._step_counter = 0
        # Body-body contact (collision.BodyContacts) or None; read with ti.static at first compile,
        # so it must be set before the first step.
        self.contacts = None
        # Serial launches evaluate each spring once; parallel ones gather without atomics.
        self.forces = ForceEvaluator(model, terrain, "per_spring" if self._serial() else "gather")

    @classmethod
    def parse_options(cls, given: dict) -> dict:
        """Defaults overlaid with ``given``; unknown names or bad values raise ``UserError``."""
        out = {name: spec[0] for name, spec in cls.OPTIONS.items()}
        for name, value in given.items():
            if name not in cls.OPTIONS:
                raise UserError(f"solver.{name}: not an option of {cls.name}; its options are {', '.join(cls.OPTIONS)}")
            _, check, allowed = cls.OPTIONS[name]
            if not check(value):
                raise UserError(f"solver.{name} = {value!r}: must be {allowed}")
            out[name] = value
        return out

    # -- public API ------------------------------------------------------------------
    def advance(self, state, dt: float, n_steps: int) -> int:
        """Advance ``state`` by up to ``n_steps`` steps of ``dt`` [s] in place.

        Returns the number of steps taken; fewer than ``n_steps`` means the last of them
        diverged (see ``diverged``). The state after a diverged step is not meaningful.
        """
        if n_steps <= 0 or self.diverged:
            return 0
        start = self._step_counter
        if self._serial():
            self._advance_serial(state.x, state.v, dt, start, n_steps)
        else:
            for k in range(n_steps):
                self._advance_parallel(state.x, state.v, dt, start + k)
        self._step_counter += n_steps
        bad = int(self.diverged_step[None])
        if bad != NOT_DIVERGED:
            return bad - start + 1
        return n_steps

    def step(self, state, dt: float) -> bool:
        """One step; returns False if it diverged."""
        return self.advance(state, dt, 1) == 1 and not self.diverged

    @property
    def diverged(self) -> bool:
        return int(self.diverged_step[None]) != NOT_DIVERGED

    def reset(self):
        """Forget divergence and any history (call after resetting the state)."""
        self.diverged_step[None] = NOT_DIVERGED
        self._step_counter = 0

    def stats(self) -> dict:
        """Per-step work counters for the run summary."""
        return {"force_evaluations_per_step": self.force_evals}

    # -- launch strategies ------------------------------------------------------------------
    def _serial(self) -> bool:
        if self.mode == "auto":
            return ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64) and self.n <= SERIAL_MAX_PARTICLES
        return self.mode == "serial"

    @ti.kernel
    def _advance_serial(self, x: ti.template(), v: ti.template(), dt: float, start: ti.i32, n_steps: ti.i32):
        ti.loop_config(serialize=True)
        for s in range(n_steps):
            self._step_body(x, v, dt, start + s)
            self._body_contacts(x, v, dt)
            if self.diverged_step[None] != NOT_DIVERGED:
                break

    @ti.kernel
    def _advance_parallel(self, x: ti.template(), v: ti.template(), dt: float, step: ti.i32):
        self._step_body(x, v, dt, step)
        self._body_contacts(x, v, dt)

    @ti.kernel
    def _k_body_contacts(self, x: ti.template(), v: ti.template(), dt: float):
        self._body_contacts(x, v, dt)

    @ti.func
    def _body_contacts(self, x: ti.template(), v: ti.template(), dt):
        """Contact between different bodies after the step (multi-body scenes only)."""
        if ti.static(self._has_contacts()):
            self.contacts.apply(x, v, dt)

    def _has_contacts(self) -> bool:
        return self.contacts is not None

    # -- shared per-particle pieces ---------------------------------------------------------
    @ti.func
    def _finish(self, i, x: ti.template(), v: ti.template(), xn, vn, step):
        """Store the stepped particle after collision response; flag divergence."""
        if ti.static(self.terrain.has_contact):
            xn, vn = self.terrain.respond(i, xn, vn)
        x[i] = xn
        v[i] = vn
        # Written so that NaN fails the test too (comparisons with NaN are false).
        if not (vn.dot(vn) <= self.speed2_limit[None]):
            ti.atomic_min(self.diverged_step[None], step)


REGISTRY: dict[str, type] = {}


def register(cls):
    """Class decorator: make an integrator available by its ``name``."""
    REGISTRY[cls.name] = cls
    return cls
