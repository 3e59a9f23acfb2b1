"""Slabs of springs for the race-free parallel scatter (forces.py, strategy ``scatter``).

The particles are split into slabs so that every spring joins a particle of its own slab to one
of the same slab or the next. The springs of slabs 0, 2, 4, ... then touch pairwise different
particles, and so do those of slabs 1, 3, 5, ...: each parity runs one slab per thread with
plain (non-atomic) adds, then the other parity.

A slab's springs are given as ranges of spring ids in the model's own order, so nothing per
spring is copied or sorted: ``(first, ranges)`` with slab k's ranges
``ranges[first[k]:first[k + 1]]``, each ``(start, end)`` (end exclusive), int32 arrays.

* A lattice body (``lattice_ranges``): slab k holds the lattice layers i = 2k, 2k + 1 (i along
  the body's first axis, whatever its rotation). Every spring offset steps 0, 1 or 2 layers up
  (``lattice.SPRING_OFFSETS``), so a spring starting in layer i ends in slab i // 2 or the next;
  within an offset, springs are ordered by their start layer, so a slab is one range per offset.
* Any other spring graph (``graph_ranges``): slabs along x at the start positions, just thicker
  than the longest spring's x extent; each spring goes to its lower end's slab; a slab is the
  runs of consecutive ids among its springs.
"""

import numpy as np

from . import lattice


def lattice_ranges(bodies) -> tuple[np.ndarray, np.ndarray]:
    """Slab ranges of lattice bodies ``[(n, first spring id), ...]`` (one model's bodies).

    Global slab k is slab k of every body (bodies share no particle). Size: 16 ranges per slab.
    """
    per_slab: dict[int, list] = {}
    for n, s0 in bodies:
        t = lattice.spring_table(n)
        for q, off in enumerate(t["off"]):
            assert off[0] >= 0, "lattice offsets step up along the first axis"
            box = [n - abs(int(o)) for o in off]  # start points of offset q
            if min(box) <= 0:
                continue
            layer = box[1] * box[2]  # springs per start layer
            for k in range((box[0] + 1) // 2):
                lo, hi = 2 * k * layer, min(2 * k + 2, box[0]) * layer
                start = s0 + int(t["base"][q])
                per_slab.setdefault(k, []).append((start + lo, start + hi))
    return _csr(per_slab)


def graph_ranges(x0, pairs) -> tuple[np.ndarray, np.ndarray]:
    """Slab ranges of any spring graph: ``x0`` [n_particles, 3] start positions [m], ``pairs``
    [n_springs, 2] particle indices (see the module docstring)."""
    pairs = np.asarray(pairs).reshape(-1, 2)
    if len(pairs) == 0:
        return _csr({})
    xs = np.asarray(x0, np.float64)[:, 0]
    a, b = pairs[:, 0], pairs[:, 1]
    thickness = float(np.abs(xs[a] - xs[b]).max()) * (1 + 1e-6) + 1e-9
    slab = np.floor((xs - xs.min()) / thickness).astype(np.int64)
    spring_slab = np.minimum(slab[a], slab[b])
    order = np.argsort(spring_slab, kind="stable")  # by slab, then by id
    key = spring_slab[order]
    # a new run where the slab changes or the ids stop being consecutive
    new = np.ones(len(order), bool)
    new[1:] = (key[1:] != key[:-1]) | (order[1:] != order[:-1] + 1)
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], len(order))
    per_slab: dict[int, list] = {}
    for s, e in zip(starts, ends):
        per_slab.setdefault(int(key[s]), []).append((int(order[s]), int(order[e - 1]) + 1))
    return _csr(per_slab)


def _csr(per_slab: dict) -> tuple[np.ndarray, np.ndarray]:
    """``{slab: [(start, end), ...]}`` -> (first [n_slabs + 1], ranges [n_ranges, 2]), int32;
    slabs without springs in between keep an empty row."""
    n_slabs = max(per_slab, default=-1) + 1
    first = np.zeros(n_slabs + 1, np.int32)
    ranges = []
    for k in range(n_slabs):
        ranges.extend(per_slab.get(k, []))
        first[k + 1] = len(ranges)
    return first, np.asarray(ranges, np.int32).reshape(-1, 2)
