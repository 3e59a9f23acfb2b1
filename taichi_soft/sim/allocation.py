"""Allocating a buffer table (``footprint.Field`` by name) as Taichi fields of an object, and the
hot per-particle vectors of the steps (``page_aligned_vectors``).

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


PAGE_BYTES = 4096


def page_aligned_vectors(n: int, count: int) -> list:
    """``count`` fields of ``n`` 3-vectors in the run's real type, in one SNode tree of their own,
    each starting on a 4 KiB page (a tree starts on one; padding between the fields).

    For the arrays every step streams through: the state (x, v), the gather's second state and the
    Runge-Kutta stage buffers. ``ti.field`` places a field in the pending tree behind whatever was
    allocated just before (a flag, a few group parameters), at an address that depends on them.
    There, the gathered semi-implicit Euler step at n = 40 in f64 ran 15-25 % slower than with the
    same four arrays in a tree of their own, in one process, interleaved (``bench.kernel_study``;
    docs/benchmarks/README.md, "Array placement"). Which placements are slow was not pinned down;
    page-aligned arrays in their own tree were fast in every arrangement tried.
    """
    real_bytes = 8 if ti.lang.impl.get_runtime().default_fp == ti.f64 else 4
    builder = ti.FieldsBuilder()
    fields = []
    for k in range(count):
        f = ti.Vector.field(3, float)
        builder.dense(ti.i, max(n, 1)).place(f)
        fields.append(f)
        gap = -(max(n, 1) * 3 * real_bytes) % PAGE_BYTES  # a multiple of 4 bytes
        if gap and k < count - 1:
            builder.dense(ti.i, gap // 4).place(ti.field(ti.i32))
    builder.finalize()
    return fields
