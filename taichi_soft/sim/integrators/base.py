"""The integrator interface every method implements, and the kernels that launch its steps.

An integrator advances a ``State`` in place: ``advance(state, dt, n_steps) -> steps_done``.
Explicit methods only write ``_step_body(x, v, dt)``, a ``ti.func`` made of loops over
particles; this base class runs it two ways from the same source:

* serial: one kernel launch runs many steps on one thread. On a CPU each parallel launch costs
  about 0.1 ms however small the loop, so small bodies (a 1000-particle cube) run several times
  faster this way;
* parallel: one launch per step, each particle loop spread over all cores (or GPU threads).

A one-stage method whose forces are gathered (each particle reads its neighbours' old state)
cannot update the state in place; it sets ``ping_pong = True`` and writes
``_step_into(x, v, xo, vo, dt, step)`` (read (x, v), write the new state to (xo, vo)); the
drivers alternate the state with a second pair of buffers and leave the result in the state.

Every step ends with ``_finish`` per particle: the terrain's collision response (projection and
restitution, the same for every method) and the divergence check (any non-finite velocity or
|v|^2 > limit); then, in scenes with several bodies, the body-body contact pass
(``self.contacts``, set by ``Simulation`` before the first step; None compiles no contact code). A diverged step stops a serial run at that step; parallel runs record the
first diverged step index.
"""

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import taichi as ti

from ... import runtime
from ..allocation import allocate, page_aligned_vectors
from ..footprint import Buffers, Counts, FieldCounts
from ..forces import ForceEvaluator, auto_strategy, pass_buffers
from ..stencil import NAME as STENCIL, StencilForces, lattice_dims, lattice_points, mask_ints
from ..linalg import SkylineCholesky
from ..scalar_fields import assign
from .options import Config, choice

# Parallel launches win above this many particles on a CPU; implicit solvers launch many kernels
# a step, so they go parallel sooner (docs/decisions/serial-launch-threshold.md).
SERIAL_MAX_PARTICLES = 4096
SERIAL_MAX_PARTICLES_EXPLICIT = 20000
NOT_DIVERGED = 2**31 - 1
# The divergence check (the assignment's): a step diverged if a velocity is non-finite or its
# |v|^2 exceeds this [m^2/s^2] (1000 m/s).
DIVERGENCE_SPEED2 = 1e6
MB = 2**20
PING_PONG = FieldCounts(6, 0, 0, 0)  # the second x, v of ping-pong steps (_use_ping_pong)


@dataclass(frozen=True)
class IntegratorConfig(Config):
    """The option every integrator has: how its steps launch."""

    # auto: serial launches on a CPU up to this many particles
    serial_max_particles: ClassVar[int] = SERIAL_MAX_PARTICLES_EXPLICIT
    mode: str = choice("auto", ("auto", "serial", "parallel"),
                       "serial: many steps per launch on one thread; parallel: one launch per step; "
                       "auto: serial for small bodies on a CPU")

    def resolve(self, arch: str, fast_math: bool, counts: Counts) -> "IntegratorConfig":
        if self.mode == "auto":
            return self.but(mode="serial" if arch == "cpu" and counts.particles <= self.serial_max_particles
                            else "parallel")
        return self


@dataclass(frozen=True)
class ExplicitConfig(IntegratorConfig):
    """The explicit methods' options: launches, and how the force pass sums spring forces."""

    # Whether ``forces = auto`` may pick the stencil (a method whose step reads the stored springs: no).
    auto_stencil: ClassVar[bool] = True
    forces: str = choice("auto", ("auto", "scatter", "per_spring", "gather", "stencil"),
                         "scatter: each spring once, added to both ends; per_spring: each spring once, stored; "
                         "gather: each particle evaluates its springs; stencil: gather with the springs found "
                         "by lattice arithmetic, none stored; auto: by backend, fast math, launches and bodies")

    def resolve(self, arch: str, fast_math: bool, counts: Counts) -> "ExplicitConfig":
        out = super().resolve(arch, fast_math, counts)
        if out.forces == "auto":
            out = out.but(forces=auto_strategy("cpu" if arch == "cpu" else "gpu", fast_math,
                                               stencil=self.auto_stencil and counts.lattice and out.mode == "parallel"
                                               and counts.real_bytes == 8))
        return out


@ti.data_oriented
class Integrator:
    """Base class. Subclasses set ``name``, ``order``, ``force_evals`` and ``_step_body(x, v, dt, step)``;
    they declare their options as ``Config`` (``ExplicitConfig``, or a subclass whose ``resolve``
    makes its own ``auto`` values concrete) and their fields per particle and spring in ``BUFFERS``
    (``{name: footprint.Field}``: this class allocates them first thing in its ``__init__`` and
    ``memory.estimate`` counts them); fields that depend on their options, by extending ``buffers``
    and allocating them themselves."""

    name = "base"
    order = 0  # global order of accuracy in dt (smooth problems)
    force_evals = 0  # force evaluations per step
    implicit = False
    # Whether its step answers an impact at the crossing time when ``contact.impact_at_crossing``
    # asks for it (``_drift``: the methods that move each particle along one path per step).
    answers_at_crossing = False
    description = ""
    # The largest step [s] the gallery gives it by default (None: the scene's dt), for a method whose
    # stability limit on the default scenes is below their dt.
    largest_default_dt = None
    # Facts every registered method declares (``register`` refuses a class without them):
    # ``amplification(h, jac)``, one step's matrix on a linear mode (linear_stability.py: the
    # divergence hint's stability limits), a staticmethod; None only for an A-stable implicit method.
    amplification = None
    # ``sweep_dt_cap`` [s]: the largest step the accuracy sweep tries (bench/sweeps.py), about the
    # method's stability limit on the sweep's cases.
    sweep_dt_cap = None
    # Whether its parallel launches want Taichi's CPU pool workers pinned one to a core (cpu_threads.py:
    # an explicit step's few long loops ran 1.5-2x faster so; the implicit solvers' many short ones slower).
    pins_pool_workers = True
    # The class's own fields per particle and spring ({name: footprint.Field}); a subclass's table adds
    # to its bases' (``buffer_table``). The base allocates them all first thing in ``__init__``.
    BUFFERS: ClassVar[dict] = {}
    # Field entries it allocates outside its table, per particle and spring (the model's adjacency
    # it asks for, a PCG's vectors).
    FIELDS = FieldCounts()
    # Peak resident memory [bytes] of a tiny run (n = 3, a few steps) on a CPU backend: the process,
    # numpy, the Taichi runtime and the compiled kernels; the midpoint of a run that compiles its
    # kernels (empty offline cache) and one that loads them (memory.py). Not measured: the largest.
    BASE_BYTES = 175 * MB
    Config = ExplicitConfig  # its options (options.py); the implicit solvers' are implicit/options.py

    def __init__(self, model, terrain, options: "dict | Config | None" = None, contacts=None):
        self.model = model
        self.terrain = terrain
        self.n = model.n_particles
        allocate(self, self.buffer_table(), self.n, model.n_springs)
        self.options = self.configure(options, *running_target(), model_counts(model))
        self.speed2_limit = ti.field(float, ())  # divergence threshold on |v|^2 [m^2/s^2]
        self.diverged_step = ti.field(ti.i32, ())
        # after both: a write closes the pending tree
        assign({self.speed2_limit: DIVERGENCE_SPEED2, self.diverged_step: NOT_DIVERGED})
        self.mode = self.options.mode
        self._step_counter = 0
        model.add_listener(self)
        # Body-body contact (contact.bodies.BodyContacts, shared by every integrator of a simulation) or
        # None: given at construction, read with ti.static when the step compiles.
        self.contacts = contacts
        # Explicit methods step through the fused force passes. Implicit solvers assemble their
        # own objective over the adjacency and allocate no force-pass buffers.
        self.forces = None
        if self.implicit:
            model.ensure_adjacency()
        else:
            strategy = self._force_strategy()
            evaluator = StencilForces if strategy == STENCIL else ForceEvaluator
            self.forces = evaluator(model, terrain, **({} if strategy == STENCIL else {"strategy": strategy}),
                                    parallel=not self._serial())
        self.ping_pong = False  # True (``_use_ping_pong``) if _step_into replaces _step_body
        self._xo = self._vo = None  # the second state buffers of ping-pong steps

    @classmethod
    def configure(cls, given: "dict | Config | None", arch: str, fast_math: bool, counts: Counts) -> Config:
        """The options from ``given`` (a ``[solver]`` table of this integrator's options, or a
        ``Config``), checked (``UserError``) and resolved for ``arch``, ``fast_math`` and ``counts``:
        what the integrator's construction and ``memory.estimate`` both use."""
        config = given if isinstance(given, Config) else cls.Config.parse(given or {}, cls.name)
        return config.resolve(arch, fast_math, counts)

    @classmethod
    def buffer_table(cls) -> dict:
        """The fields this class allocates per particle and spring: its ``BUFFERS`` and its bases'."""
        table = {}
        for klass in reversed(cls.__mro__):
            table.update(vars(klass).get("BUFFERS", {}))
        return table

    @classmethod
    def field_counts(cls) -> FieldCounts:
        """Field entries per particle and spring: the buffer table's and ``FIELDS``."""
        return FieldCounts.of(cls.buffer_table()) + cls.FIELDS

    @classmethod
    def stores_springs(cls, options: Config) -> bool:
        """Whether the model stores its springs for this integrator (all but the stencil pass's)."""
        return cls.implicit or options.forces != STENCIL

    @classmethod
    def buffers(cls, options: Config, arch: str, counts: Counts, real_bytes: int) -> Buffers:
        """What this integrator allocates for ``counts`` with ``options`` (resolved), besides the
        model's and the state's fields: the force pass's buffers (explicit methods), its buffer
        table and ``FIELDS``, and the second state of ping-pong steps. tests/test_memory.py checks
        it against the fields a real integrator allocates."""
        out = Buffers(cls.field_counts())
        if not cls.implicit and options.forces != STENCIL:
            out = out + pass_buffers(options.forces, counts, real_bytes)
        elif not cls.implicit:  # the stencil: O(bodies), and the presence mask with a mesh body
            out = out + Buffers(ints=0 if counts.lattice else mask_ints(counts.particles, counts.lattice_points))
        if cls.uses_ping_pong(options):
            out = out + Buffers(PING_PONG)
        return out

    @classmethod
    def uses_ping_pong(cls, options: Config) -> bool:
        """Whether steps with these (resolved) options go through ``_step_into`` and a second state."""
        return False

    # -- public API ------------------------------------------------------------------
    def advance(self, state, dt: float, n_steps: int) -> int:
        """Advance ``state`` by up to ``n_steps`` steps of ``dt`` [s] in place.

        Returns the number of steps taken; fewer than ``n_steps`` means the last of them
        diverged (see ``diverged``). The state after a diverged step is not meaningful.
        """
        if n_steps <= 0 or self.diverged:
            return 0
        start = self._step_counter
        x, v = state.x, state.v
        if self.ping_pong:
            xo, vo = self._xo, self._vo
            if self._serial():
                self._advance_serial_pp(x, v, xo, vo, dt, start, n_steps)
            else:
                for k in range(n_steps):
                    if k % 2 == 0:
                        self._advance_parallel_pp(x, v, xo, vo, dt, start + k)
                    else:
                        self._advance_parallel_pp(xo, vo, x, v, dt, start + k)
                if n_steps % 2 == 1:
                    self._copy_state(xo, vo, x, v)
        elif self._serial():
            with runtime.ir_passes(self._serial_ir_passes()):
                self._advance_serial(x, v, dt, start, n_steps)
        else:
            for k in range(n_steps):
                self._advance_parallel(x, v, dt, start + k)
        self._step_counter += n_steps
        bad = int(self.diverged_step[None])
        if bad != NOT_DIVERGED:
            return bad - start + 1
        return n_steps

    def _use_ping_pong(self):
        """Subclasses: steps go through ``_step_into`` and a second pair of state buffers, allocated
        here with the integrator (so the memory they take is there from the start, as counted)."""
        self.ping_pong = True
        self._xo, self._vo = page_aligned_vectors(self.n, 2)

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

    def notify_model_changed(self, flags: int):
        """The model's springs or masses changed (``model.CHANGED_*`` bits); integrators that keep
        something derived from them refresh it here. The explicit ones read the fields each step."""

    @classmethod
    def spring_passes_per_step(cls, stats: dict) -> float:
        """Passes over all springs per step (force, gradient or Hessian-product evaluations), from
        this integrator's ``stats()`` averages: the machine-independent work the benchmarks plot.
        Explicit methods: their force evaluations per step."""
        return float(cls.force_evals)

    def stats(self) -> dict:
        """Per-step work counters for the run summary."""
        return {"force_evaluations_per_step": self.force_evals}

    # -- launch strategies ------------------------------------------------------------------
    def _force_strategy(self) -> str:
        return self.options.forces  # resolved

    def _serial(self) -> bool:
        return self.mode == "serial"  # resolved

    def _serial_ir_passes(self) -> bool:
        """Whether the many-step serial kernel is compiled with Taichi's IR passes (when the runtime
        runs them); a solver whose serial kernel compiles for long and runs no faster for them says no."""
        return True

    @ti.kernel
    def _advance_serial(self, x: ti.template(), v: ti.template(), dt: float, start: ti.i32, n_steps: ti.i32):
        self._refresh()
        ti.loop_config(serialize=True)
        for s in range(n_steps):
            self._step_body(x, v, dt, start + s)
            self._body_contacts(x, v, dt)
            if self.diverged_step[None] != NOT_DIVERGED:
                break

    @ti.kernel
    def _advance_parallel(self, x: ti.template(), v: ti.template(), dt: float, step: ti.i32):
        self._refresh()
        self._step_body(x, v, dt, step)
        self._body_contacts(x, v, dt)

    @ti.kernel
    def _advance_serial_pp(self, x: ti.template(), v: ti.template(), xo: ti.template(), vo: ti.template(), dt: float,
                           start: ti.i32, n_steps: ti.i32):
        self._refresh()
        ti.loop_config(serialize=True)
        for s in range(n_steps):
            if s % 2 == 0:
                self._step_into(x, v, xo, vo, dt, start + s)
                self._body_contacts(xo, vo, dt)
            else:
                self._step_into(xo, vo, x, v, dt, start + s)
                self._body_contacts(x, v, dt)
            if self.diverged_step[None] != NOT_DIVERGED or s == n_steps - 1:
                if s % 2 == 0:  # the last step wrote the second buffers: the state must hold it
                    for i in range(self.n):
                        x[i] = xo[i]
                        v[i] = vo[i]
                break

    @ti.kernel
    def _advance_parallel_pp(self, x: ti.template(), v: ti.template(), xo: ti.template(), vo: ti.template(),
                             dt: float, step: ti.i32):
        self._refresh()
        self._step_into(x, v, xo, vo, dt, step)
        self._body_contacts(xo, vo, dt)

    @ti.func
    def _refresh(self):
        """Explicit methods: bring the force pass's copies of k, kd up to date (forces.refresh)."""
        if ti.static(self._has_forces()):
            self.forces.refresh()

    def _has_forces(self) -> bool:
        return self.forces is not None

    @ti.kernel
    def _copy_state(self, x: ti.template(), v: ti.template(), xo: ti.template(), vo: ti.template()):
        for i in range(self.n):
            xo[i] = x[i]
            vo[i] = v[i]

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
        self._check_divergence(vn, step)

    @ti.func
    def _drift(self, i, x0, v, a, dt):
        """Particle i's position [m] after drifting for ``dt`` [s] from ``x0`` at the mean velocity
        ``v`` [m/s] (acceleration ``a`` [m/s^2] along the path, zero for a constant velocity), and
        that velocity after the terrain's response to the path (``Terrain.respond_path``: at the
        end of the step, or at the crossing time)."""
        xn = x0 + dt * v
        if ti.static(self.terrain.has_contact):
            xn, v = self.terrain.respond_path(i, x0, xn, v, a, dt)
        return xn, v

    @ti.func
    def _check_divergence(self, vn, step):
        """Record ``step`` as diverged if the velocity ``vn`` is non-finite or too fast."""
        speed2 = vn.dot(vn)  # NaN if any component is NaN, inf if any is infinite
        if _not_finite(speed2) or speed2 > self.speed2_limit[None]:
            ti.atomic_min(self.diverged_step[None], step)


@ti.func
def _not_finite(s):
    """True if the float ``s`` is NaN or +-inf, read from its bits (exponent all ones).

    With fast math the compiler may assume no NaN and drop a float test such as ``s != s`` or
    ``not (s <= limit)``; integer operations on the bit pattern it must keep.
    """
    if ti.static(ti.lang.impl.get_runtime().default_fp == ti.f64):
        return ((ti.bit_cast(s, ti.i64) >> 52) & 0x7FF) == 0x7FF
    else:
        return ((ti.bit_cast(s, ti.i32) >> 23) & 0xFF) == 0xFF


def running_target() -> tuple[str, bool]:
    """(arch, fast_math) of the running Taichi, as ``Integrator.resolve`` takes them."""
    cfg = ti.lang.impl.current_cfg()
    return ("cpu" if cfg.arch in (ti.x64, ti.arm64) else "gpu"), bool(cfg.fast_math)


def running_real_bytes() -> int:
    """Bytes of the running Taichi's default float (f64: 8, f32: 4)."""
    return 8 if ti.lang.impl.current_cfg().default_fp == ti.f64 else 4


def model_counts(model) -> Counts:
    """The ``Counts`` of a built model (the envelope read from its springs, only if asked for)."""
    return Counts(model.n_particles, model.n_springs, lattice=model._lattice, real_bytes=np.dtype(model.real).itemsize,
                  lattice_points=lambda: lattice_points(lattice_dims(info) for info in model.bodies),
                  envelope=lambda: SkylineCholesky.envelope_size(model.n_particles, model.pairs_np))


REGISTRY: dict[str, type] = {}


def register(cls):
    """Class decorator: make an integrator available by its ``name``. Refuses (``TypeError``) a
    class that does not declare the facts the product needs of every method (``Integrator``:
    ``amplification`` unless implicit, ``sweep_dt_cap``)."""
    missing = [fact for fact, absent in (("amplification", cls.amplification is None and not cls.implicit),
                                         ("sweep_dt_cap", cls.sweep_dt_cap is None)) if absent]
    if missing:
        raise TypeError(f"integrator {cls.name!r} ({cls.__qualname__}) does not declare {', '.join(missing)} "
                        "(see taichi_soft.sim.integrators.base.Integrator)")
    REGISTRY[cls.name] = cls
    return cls
