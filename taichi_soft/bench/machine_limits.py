"""What this machine allows the step kernels: the copy bandwidth of a parallel Taichi kernel and
the memory-bandwidth bound of a semi-implicit step it gives (``bytes_per_step``), and how well
two threads of one parallel loop overlap in time (``thread_overlap``).
"""
from __future__ import annotations

import taichi as ti

from ..sim.forces import SLAB_STRIDE
from ..timing import time_one


# -- memory bandwidth bound ------------------------------------------------------------------------
def measured_bandwidth(mbytes: int = 256, repeats: int = 5) -> float:
    """Copy bandwidth [bytes/s] of a parallel Taichi kernel over two ``mbytes`` MB f32 fields."""
    n = mbytes * 2**20 // 4
    src = ti.field(ti.f32, n)
    dst = ti.field(ti.f32, n)

    @ti.kernel
    def copy():
        for i in src:
            dst[i] = src[i]

    return 2 * n * 4 / median_kernel_seconds(copy, repeats)


def median_kernel_seconds(kernel, repeats: int) -> float:
    """Median wall seconds of ``kernel()`` after one warm-up call (compiles), synced each time."""
    return time_one(kernel, repeats, warmup=kernel).median


def bytes_per_step(n_particles: int, n_springs: int, real_bytes: int, strategy: str, row_width: int = 0) -> int:
    """Compulsory memory traffic [bytes] of one semi-implicit Euler step (each array touched once).

    Particles: read x, v; write x, v; the force sum (scatter: written by the spring pass, read
    and cleared by the particle pass; per_spring, gather: the particle pass's own sum, free);
    inverse mass. Per spring: (k, kd). ``scatter``: ends (2 i32), rest length.
    ``per_spring``: ends, rest length, the spring force written and read; adjacency: 1 i32 per
    spring end plus offsets and splits. ``gather``: per slot of its padded rows (``row_width``
    per particle, rows.py) the other end (i32), rest length and, in f32, the (k, kd) copy (f64
    reads a group id (i32) instead: ``forces.rows_look_up_groups``).
    """
    vec = 3 * real_bytes
    particles = n_particles * (4 * vec + real_bytes)
    if strategy == "scatter":
        return particles + n_particles * 2 * vec + n_springs * (8 + 3 * real_bytes)
    if strategy == "per_spring":
        springs = n_springs * (8 + 3 * real_bytes + 2 * vec) + 2 * n_springs * 4 + 2 * n_particles * 4
    else:
        from ..sim.forces import rows_look_up_groups

        per_slot = 8 + real_bytes if rows_look_up_groups(real_bytes) else 4 + 3 * real_bytes
        springs = n_particles * row_width * per_slot
    return particles + springs


# -- how well two threads overlap on this machine ---------------------------------------------------
def thread_overlap(task_ms=(0.3, 1.0, 3.0, 10.0), repeats=21) -> list[dict]:
    """Overlap in time of the two tasks of one parallel loop, per task length (CPU backend, >= 2 threads).

    A loop whose two tasks each spin for ``task_ms`` runs in 1x the time of one task when both
    threads start at once, 2x when the second thread joins only after the first has done both.
    ``overlap`` = 2 - median(two tasks) / median(one task): 1 perfect, 0 none. The thread scaling of
    the step kernels cannot beat what this allows for loops of their length. The pool is placed as
    for an explicit step (``cpu_threads.place(True)``: its workers pinned one to a core where the
    runtime allows it): unpinned, the second worker joined late (-0.02 to 0.19 at 1 ms on the 2-core
    development VM), pinned 0.9-1.0 (cpu_threads.py).
    """
    from ..workarounds import cpu_threads

    cpu_threads.place(True)
    spin, arg = _overlap_kernel()

    def median_s(tasks, count):
        arg[0], arg[1] = tasks, count
        return median_kernel_seconds(spin, repeats)

    if "per_k" not in _OVERLAP:  # seconds per spin iteration, measured once per process
        _OVERLAP["per_k"] = median_s(1, 100000) / 100000
    per_k = _OVERLAP["per_k"]
    rows = []
    for ms in task_ms:
        count = max(1, int(ms * 1e-3 / per_k))
        one, two = median_s(1, count), median_s(2, count)
        rows.append({"task_ms": one * 1e3, "two_tasks_ms": two * 1e3, "overlap": 2.0 - two / one})
    return rows


_OVERLAP = {}  # this process's overlap kernel, its argument field (compiled once) and spin rate


def _overlap_kernel():
    """(kernel, arg): the kernel runs arg[0] tasks of one parallel loop, each spinning arg[1] times."""
    if not _OVERLAP:
        stride = SLAB_STRIDE  # one real task per stride iterations, as the parallel scatter's slabs
        sink = ti.field(ti.f32, 2)
        arg = ti.field(ti.i32, 2)  # tasks, spin count (fields: this module's annotations are strings)

        @ti.kernel
        def spin():
            for t in range(arg[0] * stride):
                if t % stride == 0:
                    acc = 0.0
                    for k in range(arg[1]):
                        acc = ti.sin(acc + k)
                    sink[t // stride] = acc

        _OVERLAP.update(kernel=spin, arg=arg, sink=sink)
    return _OVERLAP["kernel"], _OVERLAP["arg"]
