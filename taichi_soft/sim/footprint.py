"""What a run allocates, in the terms an integrator declares it (imports no Taichi: the memory check
reads it before Taichi starts).

* ``Counts``: the scene's sizes as an integrator's ``resolve`` and ``buffers`` see them: particles,
  springs and, asked for only when needed, the skyline Cholesky envelope and the gather rows' width;
* ``FieldCounts``: field entries per particle and per spring (reals: f32 or f64; 4-byte ints);
* ``Field``: one field of a buffer table, ``{name: Field}``, that a class declares once: the
  integrator base class allocates it (``integrators.base.allocate``) and ``FieldCounts.of`` counts
  it, so what a run allocates and what the memory check sums cannot differ;
* ``Buffers``: what one integrator allocates for those counts: its field entries, other entries
  (a factor's values, padded rows), and host bytes held for a moment while it is built.

Each integrator class declares its own (``Integrator.buffers``); ``memory.estimate`` sums them with
the model's and the state's (``MODEL``, ``STATE``, the same for every run).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable


@dataclass(frozen=True)
class FieldCounts:
    """Field entries of one run: reals (f32 or f64) and 4-byte ints, per particle and per spring."""

    particle_reals: int = 0
    particle_ints: int = 0
    spring_reals: int = 0
    spring_ints: int = 0

    def __add__(self, other: "FieldCounts") -> "FieldCounts":
        return FieldCounts(*(a + b for a, b in zip(self.astuple(), other.astuple())))

    def __sub__(self, other: "FieldCounts") -> "FieldCounts":
        return FieldCounts(*(a - b for a, b in zip(self.astuple(), other.astuple())))

    def astuple(self):
        return (self.particle_reals, self.particle_ints, self.spring_reals, self.spring_ints)

    @staticmethod
    def of(*tables: "dict[str, Field]") -> "FieldCounts":
        """The entries of the fields of buffer tables ``{name: Field}``."""
        out = FieldCounts()
        for table in tables:
            for f in table.values():
                counts = [0, 0, 0, 0]  # in astuple's order
                counts[2 * (f.per == "spring") + f.ints] = f.entries
                out = out + FieldCounts(*counts)
        return out

    def bytes(self, n_particles: int, n_springs: int, real_bytes: int) -> int:
        return (n_particles * (self.particle_reals * real_bytes + self.particle_ints * 4)
                + n_springs * (self.spring_reals * real_bytes + self.spring_ints * 4))


@dataclass(frozen=True)
class Field:
    """One field of a buffer table: an element per particle or per spring (``per``), real (f32 or
    f64, the run's precision) or 4-byte int (``ints``), a scalar (``shape`` ()), vector ((3,)) or
    matrix ((3, 3)) per element; ``doc`` says what it holds, with its unit."""

    per: str
    shape: tuple = ()
    ints: bool = False
    doc: str = ""

    def __post_init__(self):
        if self.per not in ("particle", "spring"):
            raise ValueError(f"Field.per: 'particle' or 'spring', not {self.per!r}")

    @property
    def entries(self) -> int:
        out = 1
        for d in self.shape:
            out *= d
        return out


def per_particle(doc: str, shape: tuple = (), ints: bool = False) -> Field:
    return Field("particle", shape, ints, doc)


def per_spring(doc: str, shape: tuple = (), ints: bool = False) -> Field:
    return Field("spring", shape, ints, doc)


VEC, MAT = (3,), (3, 3)  # the shapes of a vector and a 3x3 matrix field's elements

MODEL_SPRINGS = FieldCounts(0, 0, 1, 3)  # model.py, once stored (ensure_springs): rest, ends x2, group
MODEL = FieldCounts(2, 0, 0, 0) + MODEL_SPRINGS  # model.py: mass, inv_mass | the stored springs
STATE = FieldCounts(6, 0, 0, 0)  # state.py: x, v
ADJACENCY = FieldCounts(0, 2, 2, 6)  # Model.ensure_adjacency: adj_offset, adj_split | per spring end: rest, other, group, code


@dataclass(frozen=True)
class Buffers:
    """What an integrator allocates: ``fields`` per particle and spring, ``reals`` and ``ints`` besides
    (not proportional to either count), and ``transient`` host bytes above all of them at one moment
    of its construction (CPU backend)."""

    fields: FieldCounts = FieldCounts()
    reals: int = 0
    ints: int = 0
    transient: int = 0

    def __add__(self, other: "Buffers") -> "Buffers":
        return Buffers(self.fields + other.fields, self.reals + other.reals, self.ints + other.ints,
                       max(self.transient, other.transient))

    def bytes(self, n_particles: int, n_springs: int, real_bytes: int) -> int:
        """Field bytes (the transient is apart: it is not held)."""
        return self.fields.bytes(n_particles, n_springs, real_bytes) + self.reals * real_bytes + self.ints * 4


class Counts:
    """A scene's sizes: ``particles``, ``springs``; ``envelope`` (values of the skyline Cholesky
    factor of its spring graph), ``row_width`` (the gather strategy's padded rows, rows.py) and
    ``lattice_points`` (the bodies' lattices' points: the stencil's presence mask) are computed on
    first use from the callables given, so a choice that needs none costs nothing."""

    def __init__(self, particles: int, springs: int, envelope: Callable[[], int] | None = None,
                 row_width: Callable[[], int] | None = None, lattice: bool = False,
                 lattice_points: Callable[[], int] | None = None, real_bytes: int = 8):
        self.particles, self.springs = particles, springs
        self.real_bytes = real_bytes  # the run's float size (f64: 8): forces = auto depends on it
        self.lattice = lattice  # every body a whole lattice (cubes): the stencil needs no presence mask
        self._envelope, self._row_width, self._lattice_points = envelope, row_width, lattice_points

    @cached_property
    def envelope(self) -> int:
        return int(self._envelope())

    @cached_property
    def row_width(self) -> int:
        return int(self._row_width())

    @cached_property
    def lattice_points(self) -> int:
        """Points of the bodies' lattices (a mesh body's whole grid, kept or clipped)."""
        return int(self._lattice_points())
