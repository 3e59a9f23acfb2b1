"""Allocating the per-particle and per-spring arrays of the steps: a buffer table
(``footprint.Field`` by name) as Taichi fields of an object (``allocate``), and the state-sized
vectors every step streams through (``page_aligned_vectors``); the runtime's limit on SNode trees
(``check_tree_room``).

The table is the one home of what a class allocates per particle and per spring: this module
allocates it, ``footprint.FieldCounts.of`` counts it for the memory check.

The state-sized vectors lie in an SNode tree of their own, each field starting on a 4 KiB page.
``ti.field`` places a field in the pending tree behind whatever was allocated just
before it (a flag, a few group parameters), at an address that depends on them. There, the
gathered semi-implicit Euler step at n = 40 in f64 ran 15-25 % slower than with the same four
arrays page-aligned in a tree of their own, in one process, interleaved (``studies/kernel_study.py``;
docs/benchmarks/README.md, "Array placement"). Which placements are slow was not pinned down;
page-aligned arrays were fast in every arrangement tried.
"""
import numpy as np
import taichi as ti

from ..errors import UserError
from .footprint import Field

PAGE_BYTES = 4096
# Taichi 1.7's LLVM runtimes (CPU, CUDA) hold at most this many SNode trees (kMaxNumSnodeTreesLlvm
# in taichi/inc/constants.h) and never free one; the next tree is written past the end of the
# table: a segmentation fault, not an error.
MAX_TREES = 512
# Room kept for one more simulation or integrator: a simulation builds 8-18 trees (measured:
# semi-implicit Euler 8, RK4 9, implicit Euler 10 on one body, fast mass-spring on the pile 18).
TREES_PER_SIMULATION = 32


def allocate(owner, table: "dict[str, Field]", n_particles: int, n_springs: int):
    """Allocate the fields of ``table`` as attributes of ``owner``: an element per particle
    (``n_particles``) or per spring (``n_springs``, at least 1), in the run's real type or i32.

    In the pending tree, not page-aligned in a tree of their own: that bought the implicit solvers
    -2 to +10 % (within the spread of the rounds; docs/benchmarks/README.md, "Array placement") and
    cost two more of the runtime's trees per simulation (``MAX_TREES``)."""
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


def page_aligned_vectors(n: int, count: int) -> list:
    """``count`` fields of ``n`` 3-vectors [the run's real type] in one tree of their own, each
    starting on a page: the state (x, v), the gather's second state, the Runge-Kutta stage buffers.
    A tree starts on a page; an unused i32 array after each field fills up to the next one."""
    size = max(n, 1)
    real_bytes = 8 if ti.lang.impl.get_runtime().default_fp == ti.f64 else 4
    gap = -(size * 3 * real_bytes) % PAGE_BYTES  # a multiple of 4 bytes
    builder = ti.FieldsBuilder()
    fields = []
    for k in range(count):
        if k and gap:
            builder.dense(ti.i, gap // 4).place(ti.field(ti.i32))
        fields.append(ti.Vector.field(3, float))
        builder.dense(ti.i, size).place(fields[-1])
    builder.finalize()
    return fields


def numpy_real():
    """The numpy dtype of the running Taichi's default float: the run's precision (f64 or f32)."""
    return np.float64 if ti.lang.impl.get_runtime().default_fp == ti.f64 else np.float32


def check_tree_room():
    """Raise ``UserError`` if building one more simulation or integrator could take this Taichi
    runtime past ``MAX_TREES`` trees (a process that built about 30-60 simulations; the demo after
    many terrain changes), instead of letting Taichi crash."""
    if ti.lang.impl.current_cfg().arch not in (ti.x64, ti.arm64, ti.cuda):
        return  # the other backends have no such table
    used = ti.lang.impl.get_runtime().prog.get_snode_tree_size()
    if used + TREES_PER_SIMULATION > MAX_TREES:
        raise UserError(f"this process has built {used} of the {MAX_TREES} Taichi field trees a runtime "
                        "can hold (one simulation takes 8-18, and Taichi frees none): start a new process")
