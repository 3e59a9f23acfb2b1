"""Builder -> Model -> State: the static description of the bodies and their changing state.

``ModelBuilder`` collects bodies on the numpy side; ``finalize()`` makes a ``Model`` of Taichi
fields, writing the lattice springs on the device (no host copies of the per-spring arrays);
their adjacency is built, also on the device, only for the integrators that gather over it
(``ensure_adjacency``); ``model.state()`` allocates a ``State`` (positions and velocities).
Everything a user may tune while a run is going (stiffness, damping, gravity) lives in fields,
so changing it takes effect on the next step without recompiling a kernel.

This module is the one home of two encodings every spring kernel relies on:

* spring group ``g = body * 3 + kind`` (kind: stretch 0, shear 1, bend 2), the index into
  ``group_k`` / ``group_kd``: ``spring_group``, ``group_body``, ``group_kind``;
* the signed spring id in ``adj_spring``: ``s`` where the particle is end a of spring s, ``-s - 1``
  where it is end b: ``end_a_code``, ``end_b_code``, ``is_end_a``, ``code_spring`` and (for
  entries known to be end b, branch-free) ``end_b_spring``.

They are ``ti.pyfunc``: callable from Python and from kernels alike.
"""

import weakref
from dataclasses import dataclass

import numpy as np
import taichi as ti

from . import lattice, meshbody, slabs
from .lattice import SPRING_KINDS

N_KINDS = len(SPRING_KINDS)  # spring groups per body
# What a ``Model`` setter changed (bits of the flags given to ``notify_model_changed``).
CHANGED_SPRINGS = 1  # stiffnesses or damper coefficients
CHANGED_MASSES = 2  # particle masses, pins included


# -- the two encodings (one home; see the module docstring) ---------------------------------------
@ti.pyfunc
def spring_group(body, kind):
    """Group index of spring ``kind`` (0 stretch, 1 shear, 2 bend) of body ``body``."""
    return body * N_KINDS + kind


@ti.pyfunc
def group_body(group):
    """Body index of a spring group (works elementwise on numpy integer arrays)."""
    return group // N_KINDS


@ti.pyfunc
def group_kind(group):
    """Spring kind (0 stretch, 1 shear, 2 bend) of a group (works elementwise on numpy arrays)."""
    return group % N_KINDS


@ti.pyfunc
def end_a_code(s):
    """``adj_spring`` entry of spring s seen from its end a."""
    return s


@ti.pyfunc
def end_b_code(s):
    """``adj_spring`` entry of spring s seen from its end b (negative)."""
    return -s - 1


@ti.pyfunc
def is_end_a(code):
    """True where an ``adj_spring`` entry belongs to the spring's end a."""
    return code >= 0


@ti.pyfunc
def end_b_spring(code):
    """Spring id of an ``adj_spring`` entry known to be an end-b one (no branch)."""
    return -code - 1


@ti.pyfunc
def code_spring(code):
    """Spring id of any ``adj_spring`` entry (scalars; numpy: ``np.maximum(c, -c - 1)``)."""
    return max(code, -code - 1)


@dataclass
class BodySpec:
    """One soft body, as a scene describes it. Lengths in m, masses in kg, angles in degrees.

    ``shape = "cube"``: an n^3 lattice of edge ``size``. ``shape = "mesh"``: the lattice clipped
    to the closed triangle mesh in the file ``mesh`` (``meshbody``), n points along its longest
    side, which is ``size`` long, or the mesh scaled by ``scale`` metres per unit when given.
    """

    n: int = 10
    size: float = 4.0
    shape: str = "cube"
    mesh: str | None = None
    scale: float | None = None
    particle_mass: float = 1.0
    center: tuple = (0.0, 9.0, 0.0)
    rotation_axis: tuple = (1.0, 0.0, 1.0)
    rotation_degrees: float = 0.0
    velocity: tuple = (0.0, 0.0, 0.0)
    angular_velocity: tuple = (0.0, 0.0, 0.0)
    # Initial deformation: the start shape is the rest shape scaled per body axis (1 = at rest).
    initial_stretch: tuple = (1.0, 1.0, 1.0)
    # (stiffness [N/m], damper coefficient [N s/m]) per spring kind
    stretch: tuple = (2000.0, 60.0)
    shear: tuple = (2000.0, 60.0)
    bend: tuple = (2000.0, 60.0)


@dataclass
class BodyInfo:
    """Where a finalized body's particles, springs and surface live in the model's arrays.

    A cube's ``surface`` is its lattice's boundary. A mesh body's ``mesh`` holds its
    ``meshbody.MeshLattice`` (the input surface embedded in the lattice: what is drawn), and its
    ``surface`` is that mesh in particle terms (``meshbody.particle_surface``: what the demo picks on).
    """

    particles: slice
    springs: slice
    surface: np.ndarray  # [n_tris, 3] global particle indices, outward winding
    spec: BodySpec
    mesh: object = None


class ModelBuilder:
    """Collects bodies on the host; ``finalize()`` makes the device ``Model``."""

    def __init__(self, gravity=(0.0, -9.8, 0.0)):
        self.gravity = tuple(float(g) for g in gravity)
        self.specs: list[BodySpec] = []

    def add_cube(self, spec: BodySpec) -> int:
        """Add a soft body (a cube, or a mesh body when ``spec.shape == "mesh"``); returns its index."""
        self.specs.append(spec)
        return len(self.specs) - 1

    def finalize(self) -> "Model":
        """The device ``Model``. Host memory: x0, v0 and masses (56 bytes per particle) kept,
        one body's lattice (24 bytes per particle) as a temporary; a cube's springs are made on
        the device, a mesh body's uploaded from its (cached) ``MeshLattice``."""
        meshes = [meshbody.spec_lattice(spec, f"body.{b}.mesh") if spec.shape == "mesh" else None
                  for b, spec in enumerate(self.specs)]
        n_particles = sum(m.n_particles if m else spec.n ** 3 for spec, m in zip(self.specs, meshes))
        x0 = np.empty((n_particles, 3))
        v0 = np.empty((n_particles, 3))
        mass = np.empty(n_particles)
        bodies, group_k, group_kd, kind_counts = [], [], [], np.zeros(N_KINDS, np.int64)
        p0 = s0 = 0
        for spec, mesh in zip(self.specs, meshes):
            rot = lattice.rotation_matrix(spec.rotation_axis, spec.rotation_degrees)
            pts = mesh.points.copy() if mesh else lattice.lattice_points(spec.n, spec.size)
            pts *= np.asarray(spec.initial_stretch, dtype=np.float64)
            sl = slice(p0, p0 + len(pts))
            x, v = x0[sl], v0[sl]
            np.matmul(pts, rot.T, out=x)  # start shape about the centre
            del pts
            w = np.asarray(spec.angular_velocity, dtype=np.float64)
            # v = velocity + omega x r, written as r @ K^T with K the cross-product matrix of omega
            cross = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
            np.matmul(x, cross.T, out=v)
            v += np.asarray(spec.velocity, dtype=np.float64)
            x += np.asarray(spec.center, dtype=np.float64)
            mass[sl] = spec.particle_mass
            for k, kd in (spec.stretch, spec.shear, spec.bend):
                group_k.append(k)
                group_kd.append(kd)
            counts = mesh.spring_counts() if mesh else lattice.spring_counts(spec.n)
            kind_counts += counts
            surf = (meshbody.particle_surface(mesh) if mesh else lattice.surface_triangles(spec.n)) + p0
            bodies.append(BodyInfo(sl, slice(s0, s0 + sum(counts)), surf, spec, mesh))
            p0 += len(x)
            s0 += sum(counts)
        model = Model.__new__(Model)
        model._setup(x0, v0, mass, s0, kind_counts, group_k, group_kd, self.gravity, bodies)
        model._lattice = all(m is None for m in meshes)  # slab ranges by lattice arithmetic only for whole cubes
        for b, info in enumerate(bodies):
            spec = info.spec
            if info.mesh is not None:
                if info.mesh.n_springs:
                    m = info.mesh
                    _put_springs(model.spring_ends, model.spring_rest, model.spring_group, m.pairs,
                                 m.rest.astype(model.real), m.kind.astype(np.int32), info.particles.start,
                                 info.springs.start, spring_group(b, 0))
                continue
            lattice.fill_springs(model.spring_ends, model.spring_rest, model.spring_group, spec.n,
                                 info.particles.start, info.springs.start, spring_group(b, 0),
                                 spec.size / (spec.n - 1))
        return model


@ti.kernel
def _put_springs(ends: ti.template(), rest: ti.template(), group: ti.template(), pairs: ti.types.ndarray(ndim=2),
                 length: ti.types.ndarray(ndim=1), kind: ti.types.ndarray(ndim=1), p0: ti.i32, s0: ti.i32, g0: ti.i32):
    """Write one body's springs given as host arrays (local particle indices) at ids s0, s0 + 1, ..."""
    for s in range(pairs.shape[0]):
        ends[s0 + s] = ti.Vector([p0 + pairs[s, 0], p0 + pairs[s, 1]])
        rest[s0 + s] = ti.cast(length[s], float)
        group[s0 + s] = g0 + kind[s]


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
        if self.n_springs:
            self.spring_ends.from_numpy(pairs)
            self.spring_rest.from_numpy(np.asarray(rest, dtype=self.real))
            self.spring_group.from_numpy(group)

    def _setup(self, x0, v0, mass, n_springs, kind_counts, group_k, group_kd, gravity, bodies):
        """Allocate every field and upload the per-particle and per-group data."""
        self.n_particles = int(len(x0))
        self.n_springs = int(n_springs)
        self.n_groups = int(len(group_k))
        self.bodies: list[BodyInfo] = bodies
        self._kind_counts = {name: int(c) for name, c in zip(SPRING_KINDS, kind_counts)}
        self.x0_np = np.asarray(x0, dtype=np.float64)
        self.v0_np = np.asarray(v0, dtype=np.float64)
        self.mass_np = np.asarray(mass, dtype=np.float64)
        self.real = np.float64 if ti.lang.impl.get_runtime().default_fp == ti.f64 else np.float32
        self._lattice = False  # springs in lattice order (ModelBuilder): slab ranges by arithmetic

        n, m = self.n_particles, max(self.n_springs, 1)
        self.mass = ti.field(float, n)
        self.inv_mass = ti.field(float, n)
        self.spring_ends = ti.Vector.field(2, ti.i32, m)
        self.spring_rest = ti.field(float, m)
        self.spring_group = ti.field(ti.i32, m)
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

    @ti.kernel
    def _set_groups(self, k: ti.types.ndarray(ndim=1), kd: ti.types.ndarray(ndim=1), count: ti.i32):
        for g in range(count):
            self.group_k[g] = ti.cast(k[g], float)
            self.group_kd[g] = ti.cast(kd[g], float)

    def ensure_adjacency(self):
        """Allocate and build the adjacency fields (class docstring) unless already built.

        Call it before compiling a kernel that reads ``adj_*``: Taichi binds fields at compile time.
        """
        if self.adj_offset is not None:
            return
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
        """Spring ends [n_springs, 2] int32, downloaded from ``spring_ends`` (a new copy each call)."""
        return self.spring_ends.to_numpy()[: self.n_springs]

    @property
    def rest_np(self) -> np.ndarray:
        """Rest lengths [m], [n_springs] float64, downloaded from ``spring_rest`` (a new copy each call)."""
        return self.spring_rest.to_numpy()[: self.n_springs].astype(np.float64, copy=False)

    @property
    def group_np(self) -> np.ndarray:
        """Spring groups [n_springs] int32, downloaded from ``spring_group`` (a new copy each call)."""
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
        self.gravity[None] = tuple(float(c) for c in g)

    def spring_counts(self) -> dict:
        """Number of springs of each kind over all bodies."""
        return dict(self._kind_counts)

    def state(self) -> "State":
        """A new ``State`` at the model's initial positions and velocities."""
        s = State(self.n_particles)
        s.set(self.x0_np, self.v0_np)
        return s


@ti.data_oriented
class State:
    """Positions x [m] and velocities v [m/s] of all particles, shape [n_particles] vec3."""

    def __init__(self, n_particles: int):
        self.n_particles = n_particles
        self.x = ti.Vector.field(3, float, n_particles)
        self.v = ti.Vector.field(3, float, n_particles)

    def set(self, x: np.ndarray, v: np.ndarray):
        """Copy positions [m] and velocities [m/s], arrays [n_particles, 3], into the state.

        One kernel (no host copy when the arrays are already in the run's precision).
        """
        real = np.float64 if ti.lang.impl.get_runtime().default_fp == ti.f64 else np.float32
        arrays = []
        for name, a in (("x", x), ("v", v)):
            a = np.ascontiguousarray(a, dtype=real)
            if a.shape != (self.n_particles, 3):
                raise ValueError(f"State.set: {name} has shape {a.shape}, expected ({self.n_particles}, 3)")
            arrays.append(a)
        self._set(*arrays)

    @ti.kernel
    def _set(self, x: ti.types.ndarray(ndim=2), v: ti.types.ndarray(ndim=2)):
        for i in range(self.n_particles):
            self.x[i] = ti.cast(ti.Vector([x[i, 0], x[i, 1], x[i, 2]]), float)
            self.v[i] = ti.cast(ti.Vector([v[i, 0], v[i, 1], v[i, 2]]), float)

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of (x, v) as numpy arrays [n_particles, 3] in the run's precision."""
        return self.x.to_numpy(), self.v.to_numpy()

    def copy_from(self, other: "State"):
        self.x.copy_from(other.x)
        self.v.copy_from(other.v)
