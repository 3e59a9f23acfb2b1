"""Allocating a buffer table (``footprint.Field`` by name) as Taichi fields of an object.

The table is the one home of what a class allocates per particle and per spring: this module
allocates it, ``footprint.FieldCounts.of`` counts it for the memory check.
"""
import taichi as ti

from .footprint import Field


def allocate(owner, table: "dict[str, Field]", n_particles: int, n_springs: int):
    """Allocate the fields of ``table`` as attributes of ``owner``: an element per particle
    (``n_particles``) or per spring (``n_springs``, at least 1), in the run's real type or i32."""
    for name, f in table.items():
        size = n_particles if f.per == "particle" else max(n_springs, 1)
        dtype = ti.i32 if f.ints else float
        if len(f.shape) == 0:
            field = ti.field(dtype, size)
        elif len(f.shape) == 1:
            field = ti.Vector.field(f.shape[0], dtype, size)
        else:
            field = ti.Matrix.field(*f.shape, dtype, size)
        setattr(owner, name, field)
