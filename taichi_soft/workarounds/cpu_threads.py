"""One core per worker of Taichi's CPU thread pool (Linux).

Taichi 1.7's CPU backend runs each parallel loop on a pool of worker threads, which the launching
thread wakes through a condition variable at every launch and which go back to sleep when the loop
ends. Linux puts a woken thread on the waker's core when it can (wake-affine placement), and after
most short launches both workers had last run on the same core: the two tasks of one short
parallel loop then run one after the other, and a step kernel at n = 40, launched every few ms,
waits for that at every step. Pinning only the pool's workers leaves the launching (Python) thread
and Taichi's compile threads free to move.

Pinning is not always faster: the implicit solvers' step, one launch of many short loops, ran
slower pinned. So each integrator says which it wants (``Integrator.pins_pool_workers``) and
``Simulation.advance`` places the pool for it (``place``). The measurements:
docs/decisions/thread-pinning.md.

``want_pinning`` (``runtime.init``) says whether this runtime may pin; the first ``place(True)``
then finds the workers by what they do (``find_pool_workers``: the threads other than the caller
that spend CPU time on a parallel loop of about 0.1 s, a spin compiled and launched once per
runtime). A run whose steps launch serially never asks, and never pays for the finding.
"""

import os
import sys
import threading

import taichi as ti

SPIN_TASKS = 4096  # iterations of the finding loop; each about 20 us of sin() on this VM
SPIN_WORK = 1000  # sin() evaluations per iteration
FIND_TRIES = 10  # finding loops at most, until as many threads as the pool has spent CPU time

# The running runtime's pool: whether it may be pinned and has been searched for, its workers' thread
# ids (empty: none found, or not searched), the cores the process may use, whether they are pinned now.
_pool = {"wanted": False, "searched": False, "workers": [], "cores": [], "pinned": False}


def want_pinning(wanted: bool):
    """A new runtime started: forget the last one's pool; ``wanted``: ``place(True)`` may pin this one's."""
    _pool.update(wanted=bool(wanted), searched=False, workers=[], cores=[], pinned=False)


def _thread_cpu_ticks() -> dict[int, int]:
    """{thread id: user + system CPU time [clock ticks]} of this process's threads (Linux /proc)."""
    out = {}
    for name in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{name}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        out[int(name)] = int(fields[11]) + int(fields[12])  # utime, stime (fields 14, 15 of stat)
    return out


def _spin_kernel():
    @ti.kernel
    def spin(tasks: ti.i32) -> ti.f32:
        total = ti.cast(0.0, ti.f32)
        for t in range(tasks):
            acc = ti.cast(t, ti.f32)
            for k in range(SPIN_WORK):
                acc = ti.sin(acc + k)
            total += acc
        return total

    return spin


def find_pool_workers() -> int:
    """Find the workers of the running CPU runtime's thread pool (``place`` pins them); returns how
    many were found (0 where there is nothing to place: not Linux, one core, a pool of one thread,
    or no worker found)."""
    _pool.update(searched=True, workers=[], cores=[], pinned=False)
    if not sys.platform.startswith("linux") or not hasattr(os, "sched_setaffinity"):
        return 0
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < 2:
        return 0
    size = int(ti.lang.impl.current_cfg().cpu_max_num_threads)  # the pool's threads
    if size < 2:
        return 0
    spin = _spin_kernel()
    spin(1)  # compiles (Taichi's compile threads work now, not during the finding loop)
    me = threading.get_native_id()  # the launching thread waits while the pool works
    before = _thread_cpu_ticks()
    for _ in range(FIND_TRIES):  # on a busy machine a worker may get no tick in one loop
        spin(SPIN_TASKS)
        after = _thread_cpu_ticks()
        spent = {t: ticks - before[t] for t, ticks in after.items() if t != me and t in before}
        busy = sorted((t for t in spent if spent[t] > 0), key=lambda t: -spent[t])
        if len(busy) >= size:
            break
    workers = sorted(busy[:size])
    if len(workers) < 2:
        return 0
    _pool.update(workers=workers, cores=cores)
    return len(workers)


def place(pinned: bool):
    """Pin the pool's workers one to a core, round robin over the cores this process may use
    (``pinned``), or let them run on any of those cores; the first pinning of a runtime that wants
    it finds them. Nothing to do where none were found, or they are placed so already."""
    if pinned and _pool["wanted"] and not _pool["searched"]:
        find_pool_workers()
    if not _pool["workers"] or _pool["pinned"] == pinned:
        return
    cores = _pool["cores"]
    for k, tid in enumerate(_pool["workers"]):
        try:
            os.sched_setaffinity(tid, {cores[k % len(cores)]} if pinned else set(cores))
        except OSError:  # the thread ended, or a policy forbids it: leave it as it is
            pass
    _pool["pinned"] = pinned
