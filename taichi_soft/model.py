"""Builder -> Model -> State: the static description of the bodies and their changing state.

``ModelBuilder`` collects bodies on the numpy side; ``finalize()`` uploads them into a ``Model``
of Taichi fields; ``model.state()`` allocates a ``State`` (positions and velocities).
Everything a user may tune while a run is going (stiffness, damping, gravity) lives in fields,
so changing it takes effect on the next step without recompiling a kernel.
"""

from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from . import lattice
from .lattice import SPRING_KINDS


@dataclass
class BodySpec:
    """One soft cube, as a scene describes it. Lengths in m, masses in kg, angles in degrees."""

    n: int = 10
    size: float = 4.0
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
    """Where a finalized body's particles, springs and surface live in the model's arrays."""

    particles: slice
    springs: slice
    surface: np.ndarray  # [n_tris, 3] global particle indices, outward winding
    spec: BodySpec
    spring_counts: dict = field(default_factory=dict)


class ModelBuilder:
    """Collects bodies on the host; ``finalize()`` makes the device ``Model``."""

    def __init__(self, gravity=(0.0, -9.8, 0.0)):
        self.gravity = tuple(float(g) for g in gravity)
        self.specs: list[BodySpec] = []

    def add_cube(self, spec: BodySpec) -> int:
        """Add a soft cube; returns its body index."""
        self.specs.append(spec)
        return len(self.specs) - 1

    def finalize(self) -> "Model":
        xs, rests, vs, masses, bodies = [], [], [], [], []
        pairs, groups, surfaces = [], [], []
        group_k, group_kd = [], []
        p0 = s0 = 0
        for b, spec in enumerate(self.specs):
            rot = lattice.rotation_matrix(spec.rotation_axis, spec.rotation_degrees)
            rest_local = lattice.lattice_points(spec.n, spec.size)
            local = (rest_local * np.asarray(spec.initial_stretch, dtype=np.float64)) @ rot.T
            center = np.asarray(spec.center, dtype=np.float64)
            omega = np.asarray(spec.angular_velocity, dtype=np.float64)
            xs.append(local + center)
            rests.append(rest_local @ rot.T + center)
            vs.append(np.asarray(spec.velocity, dtype=np.float64) + np.cross(omega, local))
            masses.append(np.full(len(local), spec.particle_mass))
            bp, bk = lattice.lattice_springs(spec.n)
            pairs.append(bp + p0)
            groups.append(bk + 3 * b)  # spring group = body * 3 + kind
            for k, kd in (spec.stretch, spec.shear, spec.bend):
                group_k.append(k)
                group_kd.append(kd)
            surf = lattice.surface_triangles(spec.n) + p0
            surfaces.append(surf)
            counts = {name: int((bk == i).sum()) for i, name in enumerate(SPRING_KINDS)}
            bodies.append(BodyInfo(slice(p0, p0 + len(local)), slice(s0, s0 + len(bp)), surf, spec, counts))
            p0 += len(local)
            s0 += len(bp)
        x = np.concatenate(xs)
        x_rest = np.concatenate(rests)
        pairs = np.concatenate(pairs)
        rest = np.linalg.norm(x_rest[pairs[:, 0]] - x_rest[pairs[:, 1]], axis=1)
        return Model(
            x0=x, v0=np.concatenate(vs), mass=np.concatenate(masses), pairs=pairs,
            rest=rest, group=np.concatenate(groups), group_k=np.array(group_k, dtype=np.float64),
            group_kd=np.array(group_kd, dtype=np.float64), gravity=self.gravity, bodies=bodies,
        )


@ti.data_oriented
class Model:
    """Static particles and springs on the device.

    Fields (``float`` is the run's precision, f32 or f64):
      mass, inv_mass      [n_particles]            particle mass [kg] and its inverse (0 = pinned)
      spring_ends         [n_springs] ivec2        particle indices a, b
      spring_rest         [n_springs]              rest length [m]
      spring_group        [n_springs]              body * 3 + kind (stretch 0, shear 1, bend 2)
      group_k, group_kd   [3 n_bodies]             stiffness [N/m], damper coefficient [N s/m]
      adj_offset          [n_particles + 1]        CSR row starts of each particle's springs
      adj_other, adj_rest, adj_group [2 n_springs] the other end, rest length, group per entry
      adj_spring          [2 n_springs]            spring id s if the particle is end a, else -s - 1
      adj_split           [n_particles]            where a particle's "end b" entries begin (its
                                                   "end a" entries come first: no sign branch)
      gravity             0-d vec3                 [m/s^2]
    The adjacency lets force kernels gather over a particle's springs without atomics.
    """

    def __init__(self, x0, v0, mass, pairs, rest, group, group_k, group_kd, gravity, bodies):
        self.n_particles = int(len(x0))
        self.n_springs = int(len(pairs))
        self.n_groups = int(len(group_k))
        self.bodies: list[BodyInfo] = bodies
        self.x0_np = np.asarray(x0, dtype=np.float64)
        self.v0_np = np.asarray(v0, dtype=np.float64)
        self.mass_np = np.asarray(mass, dtype=np.float64)
        self.pairs_np = np.asarray(pairs, dtype=np.int64)
        self.rest_np = np.asarray(rest, dtype=np.float64)
        self.group_np = np.asarray(group, dtype=np.int64)

        n, m = self.n_particles, max(self.n_springs, 1)
        self.mass = ti.field(float, n)
        self.inv_mass = ti.field(float, n)
        self.spring_ends = ti.Vector.field(2, ti.i32, m)
        self.spring_rest = ti.field(float, m)
        self.spring_group = ti.field(ti.i32, m)
        self.group_k = ti.field(float, self.n_groups)
        self.group_kd = ti.field(float, self.n_groups)
        self.adj_offset = ti.field(ti.i32, n + 1)
        self.adj_other = ti.field(ti.i32, 2 * m)
        self.adj_rest = ti.field(float, 2 * m)
        self.adj_group = ti.field(ti.i32, 2 * m)
        self.adj_spring = ti.field(ti.i32, 2 * m)
        self.adj_split = ti.field(ti.i32, n)
        self.gravity = ti.Vector.field(3, float, ())

        self.real = np.float64 if ti.lang.impl.get_runtime().default_fp == ti.f64 else np.float32
        self.mass.from_numpy(self.mass_np.astype(self.real))
        self.inv_mass.from_numpy(np.where(self.mass_np > 0, 1.0 / np.maximum(self.mass_np, 1e-300), 0.0).astype(self.real))
        if self.n_springs:
            self.spring_ends.from_numpy(self.pairs_np.astype(np.int32))
            self.spring_rest.from_numpy(self.rest_np.astype(self.real))
            self.spring_group.from_numpy(self.group_np.astype(np.int32))
            self._upload_adjacency()
        self.group_k.from_numpy(np.asarray(group_k, dtype=self.real))
        self.group_kd.from_numpy(np.asarray(group_kd, dtype=self.real))
        self.gravity[None] = gravity
        self.mass_version = 0  # bumped by set_particle_mass

    def _upload_adjacency(self):
        a, b = self.pairs_np[:, 0], self.pairs_np[:, 1]
        owner = np.concatenate([a, b])
        other = np.concatenate([b, a])
        spring = np.concatenate([np.arange(self.n_springs)] * 2)
        order = np.argsort(owner, kind="stable")
        counts = np.bincount(owner, minlength=self.n_particles)
        offset = np.concatenate([[0], np.cumsum(counts)])
        self.adj_offset.from_numpy(offset.astype(np.int32))
        self.adj_other.from_numpy(other[order].astype(np.int32))
        self.adj_rest.from_numpy(self.rest_np[spring[order]].astype(self.real))
        self.adj_group.from_numpy(self.group_np[spring[order]].astype(np.int32))
        signed = np.concatenate([np.arange(self.n_springs), -np.arange(self.n_springs) - 1])
        self.adj_spring.from_numpy(signed[order].astype(np.int32))
        # The stable sort keeps each particle's "end a" entries (first half of `owner`) first.
        split = offset[:-1] + np.bincount(a, minlength=self.n_particles)
        self.adj_split.from_numpy(split.astype(np.int32))

    # -- run-time parameters -------------------------------------------------------------
    def set_spring_params(self, body: int, kind: str, k: float | None = None, damping: float | None = None):
        """Change one body's stiffness [N/m] and/or damper coefficient [N s/m] of one spring kind."""
        g = 3 * body + SPRING_KINDS.index(kind)
        if k is not None:
            self.group_k[g] = k
        if damping is not None:
            self.group_kd[g] = damping

    def set_particle_mass(self, mass: float, body: int | None = None):
        """Set the mass [kg] of every free particle (of one body, or of all); pinned ones stay pinned.

        Bumps ``mass_version`` so solvers that factorise a mass matrix know to refactorise.
        """
        sel = np.ones(self.n_particles, bool) if body is None else np.zeros(self.n_particles, bool)
        if body is not None:
            sel[self.bodies[body].particles] = True
        free = self.mass_np > 0
        self.mass_np = np.where(sel & free, float(mass), self.mass_np)
        self.mass.from_numpy(self.mass_np.astype(self.real))
        self.inv_mass.from_numpy(np.where(self.mass_np > 0, 1.0 / np.maximum(self.mass_np, 1e-300), 0.0).astype(self.real))
        self.mass_version += 1

    def set_gravity(self, g):
        """Gravity [m/s^2] as a 3-vector."""
        self.gravity[None] = tuple(float(c) for c in g)

    def spring_counts(self) -> dict:
        """Number of springs of each kind over all bodies."""
        return {name: int((self.group_np % 3 == i).sum()) for i, name in enumerate(SPRING_KINDS)}

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
        """Copy positions [m] and velocities [m/s], arrays [n_particles, 3], into the state."""
        real = np.float64 if ti.lang.impl.get_runtime().default_fp == ti.f64 else np.float32
        self.x.from_numpy(np.asarray(x, dtype=real))
        self.v.from_numpy(np.asarray(v, dtype=real))

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of (x, v) as numpy arrays [n_particles, 3] in the run's precision."""
        return self.x.to_numpy(), self.v.to_numpy()

    def copy_from(self, other: "State"):
        self.x.copy_from(other.x)
        self.v.copy_from(other.v)
