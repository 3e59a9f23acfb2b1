"""Builder -> Model -> State: the static description of the bodies on the device.

``builder.ModelBuilder`` collects bodies (``bodies.BodySpec``) and ``finalize()`` makes a ``Model``
of Taichi fields; the springs' adjacency is built, also on the device, only for the integrators
that gather over it (``ensure_adjacency``); ``model.state()`` allocates a ``state.State``
(positions and velocities). Everything a user may tune while a run is going (stiffness, damping,
gravity) lives in fields, so changing it takes effect on the next step without recompiling a
kernel; the setters tell the model's listeners what they changed (the ``CHANGED_*`` bits).

The spring-group and adjacency encodings live in ``spring_codes`` (imported here too, by their
old path, for the modules that still take them from ``model``).
"""

import weakref

import numpy as np
import taichi as ti

from . import slabs
from .allocation import numpy_real
from .bodies import BodyInfo
from .lattice import SPRING_KINDS
from .scalar_fields import assign
from .spring_codes import (N_KINDS, code_spring, end_a_code, end_b_code, end_b_spring, group_kind, is_end_a,
                           spring_group)
from .state import State

# What a ``Model`` setter changed (bits of the flags given to ``notify_model_changed``).
CHANGED_SPRINGS = 1  # stiffnesses or damper coefficients
CHANGED_MASSES = 2  # particle masses, pins included


@ti.data_oriented
class Model:
    """Static particles and springs on the device.

    Fields (``float`` is the run's precision, f32 or f64):
      mass, inv_mass      [n_particles]            particle mass [kg] and its inverse (0 = pinned)
      spring_ends         [n_springs] ivec2        particle indices a, b
      spring_rest         [n_springs]              rest length [m]
      spring_group        [n_springs]              ``spring_group(body, kind)`` (stretch 0, shear 1, bend 2)
      group_k, group_kd   [3 n_bodies]             stiffness [N/m], damper coefficient [N s/m]
      gravity             0-d vec3                 [m/s^2]
    (the three spring fields only once ``ensure_springs()`` has run: every force pass but the
    stencil's, the adjacency and the host views ask for them)
    and, once ``ensure_adjacency()`` has run (gathering force strategies, implicit solvers):
      adj_offset          [n_particles + 1]        CSR row starts of each particle's springs
      adj_other, adj_rest, adj_group [2 n_springs] the other end, rest length, group per entry
      adj_spring          [2 n_springs]            ``end_a_code(s)`` if the particle is end a, else ``end_b_code(s)``
      adj_split           [n_particles]            where a particle's "end b" entries begin (its
                                                   "end a" entries come first: no sign branch)
    The adjacency lets force kernels gather over a particle's springs without atomics. Each
    particle's entries are its "end a" springs by increasing id, then its "end b" ones likewise.
    It costs 2 ints per particle and 2 reals + 6 ints per spring, more than the springs
    themselves, so a run whose kernels do not read it (the scatter strategy) never allocates it.

    Host copies: ``x0_np``, ``v0_np`` (initial state, float64 [n_particles, 3]) and ``mass_np``
    are kept (resets and diagnostics read them); ``pairs_np``, ``rest_np`` and ``group_np`` are
    downloaded from the fields on each access (a fresh copy, for the few readers that need them).

    ``Model(x0, v0, mass, pairs, rest, group, ...)`` takes any spring graph as host arrays;
    ``ModelBuilder`` makes lattice models without host spring arrays.
    """

    def __init__(self, x0, v0, mass, pairs, rest, group, group_k, group_kd, gravity, bodies):
        pairs = np.asarray(pairs, dtype=np.int32).reshape(-1, 2)
        group = np.asarray(group, dtype=np.int32)
        kinds = np.bincount(group_kind(group), minlength=N_KINDS) if len(group) else np.zeros(N_KINDS, np.int64)
        self._setup(x0, v0, mass, len(pairs), kinds, group_k, group_kd, gravity, bodies)

        def upload(model):
            if model.n_springs:
                model.spring_ends.from_numpy(pairs)
                model.spring_rest.from_numpy(np.asarray(rest, dtype=model.real))
                model.spring_group.from_numpy(group)

        self._spring_filler = upload
        self.ensure_springs()

    def _setup(self, x0, v0, mass, n_springs, kind_counts, group_k, group_kd, gravity, bodies, springs=True):
        """Allocate every field and upload the per-particle and per-group data."""
        self.n_particles = int(len(x0))
        self.n_springs = int(n_springs)
        self.n_groups = int(len(group_k))
        self.bodies: list[BodyInfo] = bodies
        self._kind_counts = {name: int(c) for name, c in zip(SPRING_KINDS, kind_counts)}
        self.x0_np = np.asarray(x0, dtype=np.float64)
        self.v0_np = np.asarray(v0, dtype=np.float64)
        self.mass_np = np.asarray(mass, dtype=np.float64)
        self.real = numpy_real()
        self._lattice = False  # springs in lattice order (ModelBuilder): slab ranges by arithmetic

        n = self.n_particles
        self.mass = ti.field(float, n)
        self.inv_mass = ti.field(float, n)
        # The stored springs (``ensure_springs``): allocated only for the passes that read them; the
        # stencil force pass (stencil.py) finds a lattice's springs by index arithmetic instead.
        self.spring_ends = self.spring_rest = self.spring_group = None
        self._spring_filler = None  # writes the springs into the fields (set by the builder)
        if springs:  # here, in the model's own tree (no tree of their own: the runtime holds few)
            self._allocate_springs()
        self.stencil = None  # stencil.LatticeStencil, once a stencil pass was built on this model
        # Written only through the set_* methods below, which tell the listeners (a solver that
        # factorised a matrix from them must know): kernels read them, nothing else writes them.
        self.group_k = ti.field(float, max(self.n_groups, 1))
        self.group_kd = ti.field(float, max(self.n_groups, 1))
        self.adj_offset = self.adj_other = self.adj_rest = self.adj_group = self.adj_spring = None
        self.adj_split = None  # allocated by ensure_adjacency
        self.gravity = ti.Vector.field(3, float, ())
        # A hand pulling one particle (``grab.attach``: the demo's mouse); read with ti.static when
        # a step compiles, so a model without one compiles no grab code.
        self.grab = None

        # Kernel arguments in the run's precision: backends without f64 (Vulkan, Metal) take them.
        self._set_mass(self.mass_np.astype(self.real, copy=False))
        self._set_groups(np.asarray(group_k, dtype=self.real), np.asarray(group_kd, dtype=self.real), len(group_k))
        self.set_gravity(gravity)
        self._listeners = weakref.WeakSet()  # told of each change (``add_listener``)

    @ti.kernel
    def _set_mass(self, mass: ti.types.ndarray(ndim=1)):
        for i in range(self.n_particles):
            mi = ti.cast(mass[i], float)
            self.mass[i] = mi
            self.inv_mass[i] = 1.0 / mi if mi > 0 else 0.0

    @ti.func
    def free(self, i):
        """Whether particle i moves under forces (inverse mass > 0); a pinned one follows its own
        velocity."""
        return self.inv_mass[i] > 0

    @ti.kernel
    def _set_groups(self, k: ti.types.ndarray(ndim=1), kd: ti.types.ndarray(ndim=1), count: ti.i32):
        for g in range(count):
            self.group_k[g] = ti.cast(k[g], float)
            self.group_kd[g] = ti.cast(kd[g], float)

    def ensure_springs(self):
        """Allocate and write the spring fields unless already there (every pass but the stencil's
        reads them). Call it before compiling a kernel that reads them."""
        if self._spring_filler is None:
            return  # written already, or by the caller
        if self.spring_ends is None:
            self._allocate_springs()
        filler, self._spring_filler = self._spring_filler, None
        filler(self)

    def springs_stored(self) -> bool:
        """Whether the spring fields (``spring_ends``, ``spring_rest``, ``spring_group``) exist."""
        return self.spring_ends is not None

    def _allocate_springs(self):
        m = max(self.n_springs, 1)
        self.spring_ends = ti.Vector.field(2, ti.i32, m)
        self.spring_rest = ti.field(float, m)
        self.spring_group = ti.field(ti.i32, m)

    def pairs_among(self, near) -> np.ndarray:
        """Spring ends [k, 2] int32 of the springs whose two ends are both ``near`` (a bool mask
        over particles), from the stored springs, or without them from the lattice (cube bodies) and
        the mesh bodies' host springs."""
        if self.springs_stored():
            ends = self.pairs_np
            return ends[near[ends[:, 0]] & near[ends[:, 1]]]
        from .lattice import lattice_pairs_among

        parts = []
        for info in self.bodies:
            if info.mesh is None:
                parts.append(lattice_pairs_among(info.spec.n, info.particles.start, near[info.particles]))
            else:  # the mesh body's (cached, host) springs
                ends = info.mesh.pairs + np.int32(info.particles.start)
                parts.append(ends[near[ends[:, 0]] & near[ends[:, 1]]])
        return np.concatenate(parts) if parts else np.zeros((0, 2), np.int32)

    def ensure_adjacency(self):
        """Allocate and build the adjacency fields (class docstring) unless already built.

        Call it before compiling a kernel that reads ``adj_*``: Taichi binds fields at compile time.
        """
        if self.adj_offset is not None:
            return
        self.ensure_springs()
        n, m = self.n_particles, max(self.n_springs, 1)
        self.adj_offset = ti.field(ti.i32, n + 1)
        self.adj_other = ti.field(ti.i32, 2 * m)
        self.adj_rest = ti.field(float, 2 * m)
        self.adj_group = ti.field(ti.i32, 2 * m)
        self.adj_spring = ti.field(ti.i32, 2 * m)
        self.adj_split = ti.field(ti.i32, n)
        self._build_adjacency()

    def slab_ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """The springs split into slabs for the parallel scatter: (first, ranges), see ``slabs``."""
        if self._lattice:
            return slabs.lattice_ranges([(info.spec.n, info.springs.start) for info in self.bodies])
        return slabs.graph_ranges(self.x0_np, self.pairs_np)

    @ti.func
    def _adjacency_key(self, code):
        """Sort key of an adjacency entry: end-a entries first, each run by increasing spring id."""
        key = code
        if not is_end_a(code):
            key = self.n_springs + end_b_spring(code)
        return key

    @ti.kernel
    def _build_adjacency(self):
        """CSR adjacency of ``spring_ends`` on the device, in place in the adj_* fields.

        Count each particle's entries, prefix-sum them (serial: one pass over particles), place
        each spring's two codes at per-particle cursors (atomic, so in any order), then sort each
        particle's few entries by ``_adjacency_key`` (deterministic result) and gather the other
        end, rest length and group of every entry.
        """
        n, m = self.n_particles, self.n_springs
        for i in range(n + 1):
            self.adj_offset[i] = 0
        for s in range(m):
            ti.atomic_add(self.adj_offset[self.spring_ends[s][0] + 1], 1)
            ti.atomic_add(self.adj_offset[self.spring_ends[s][1] + 1], 1)
        ti.loop_config(serialize=True)
        for i in range(n):
            self.adj_offset[i + 1] += self.adj_offset[i]
        for i in range(n):
            self.adj_split[i] = self.adj_offset[i]  # used as the fill cursor first
        for s in range(m):
            self.adj_spring[ti.atomic_add(self.adj_split[self.spring_ends[s][0]], 1)] = end_a_code(s)
            self.adj_spring[ti.atomic_add(self.adj_split[self.spring_ends[s][1]], 1)] = end_b_code(s)
        for i in range(n):
            lo, hi = self.adj_offset[i], self.adj_offset[i + 1]
            for e in range(lo + 1, hi):  # insertion sort: a particle has at most a few dozen entries
                code = self.adj_spring[e]
                key = self._adjacency_key(code)
                f = e
                while f > lo and self._adjacency_key(self.adj_spring[f - 1]) > key:
                    self.adj_spring[f] = self.adj_spring[f - 1]
                    f -= 1
                self.adj_spring[f] = code
            split = lo
            for e in range(lo, hi):
                code = self.adj_spring[e]
                s = code_spring(code)
                other = self.spring_ends[s][0]
                if is_end_a(code):
                    other = self.spring_ends[s][1]
                    split += 1
                self.adj_other[e] = other
                self.adj_rest[e] = self.spring_rest[s]
                self.adj_group[e] = self.spring_group[s]
            self.adj_split[i] = split

    # -- host views (downloads; see the class docstring) -----------------------------------------
    @property
    def pairs_np(self) -> np.ndarray:
        """Spring ends [n_springs, 2] int32, downloaded from ``spring_ends`` (a new copy each call;
        stores the springs first if they were not)."""
        self.ensure_springs()
        return self.spring_ends.to_numpy()[: self.n_springs]

    @property
    def rest_np(self) -> np.ndarray:
        """Rest lengths [m], [n_springs] float64, downloaded from ``spring_rest`` (a new copy each call)."""
        self.ensure_springs()
        return self.spring_rest.to_numpy()[: self.n_springs].astype(np.float64, copy=False)

    @property
    def group_np(self) -> np.ndarray:
        """Spring groups [n_springs] int32, downloaded from ``spring_group`` (a new copy each call)."""
        self.ensure_springs()
        return self.spring_group.to_numpy()[: self.n_springs]

    # -- run-time parameters -------------------------------------------------------------
    # Each setter tells the listeners what it changed (``notify_model_changed(flags)``, flags the
    # CHANGED_* bits): a solver that keeps something derived from the model (a factorised matrix,
    # the total mass) refreshes only that, when told, instead of polling the fields every step.
    def add_listener(self, listener):
        """Call ``listener.notify_model_changed(flags)`` after each change (held weakly: a replaced
        integrator stops listening when it is dropped)."""
        self._listeners.add(listener)

    def _changed(self, flags: int):
        for listener in list(self._listeners):
            listener.notify_model_changed(flags)

    def set_spring_params(self, body: int, kind: str, k: float | None = None, damping: float | None = None):
        """Change one body's stiffness [N/m] and/or damper coefficient [N s/m] of one spring kind."""
        g = spring_group(body, SPRING_KINDS.index(kind))
        if k is not None:
            self.group_k[g] = k
        if damping is not None:
            self.group_kd[g] = damping
        self._changed(CHANGED_SPRINGS)

    def set_group_stiffness(self, k):
        """Every spring group's stiffness [N/m] at once (an array of ``n_groups`` values)."""
        k = np.asarray(k, dtype=np.float64)
        self._set_groups(k.astype(self.real), self.group_kd.to_numpy()[: self.n_groups].astype(self.real), self.n_groups)
        self._changed(CHANGED_SPRINGS)

    def set_particle_mass(self, mass: float, body: int | None = None):
        """Set the mass [kg] of every free particle (of one body, or of all); pinned ones stay pinned."""
        sel = slice(None) if body is None else self.bodies[body].particles
        part = self.mass_np[sel]
        part[part > 0] = float(mass)
        self._set_mass(self.mass_np.astype(self.real, copy=False))
        self._changed(CHANGED_MASSES)

    def has_grab(self) -> bool:
        """Whether steps on this model include a grab (``grab.attach``); a compile-time constant."""
        return self.grab is not None

    def set_masses(self, particles, mass: float):
        """Set the mass [kg] of the ``particles`` (indices or a mask); 0 pins them (inverse mass 0:
        forces no longer move them, every integrator keeps them at their own velocity)."""
        self.mass_np[particles] = float(mass)
        self._set_mass(self.mass_np.astype(self.real, copy=False))
        self._changed(CHANGED_MASSES)

    def set_gravity(self, g):
        """Gravity [m/s^2] as a 3-vector."""
        assign({self.gravity: g})

    def spring_counts(self) -> dict:
        """Number of springs of each kind over all bodies."""
        return dict(self._kind_counts)

    def state(self) -> "State":
        """A new ``State`` at the model's initial positions and velocities."""
        s = State(self.n_particles)
        s.set(self.x0_np, self.v0_np)
        return s
