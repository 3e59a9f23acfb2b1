"""A Vulkan fault (Taichi 1.7.4 on Mesa's lavapipe 22.3.6), reduced from the implicit pair list
(pair_list._find): an i32 atomic inside a loop whose bounds are known only at run time ends the
loop one iteration early, and the thread then skips everything after the loop, even when the
atomic's branch is never taken. f32 atomics, constant-bound loops and loops without an atomic run
right; so does the CPU backend.

    .venv/bin/python scripts/vulkan_atomic_in_loop.py      # exit 1 if the fault shows, 0 if not

Measured 2026-12-08 on the 2-core Intel Xeon VM: each of 100 threads loops over range(6, 10)
(bounds read from a field, or kernel arguments) with ``ti.atomic_add`` on an i32 field: the
counter reads 300, not 400, and the i32 counter after the loop 0, not 100; with one thread 3 and
0. The same with Taichi's IR passes on or off. In the project, ``_find`` appends each candidate
pair with ``ti.atomic_add(n_pairs, 1)`` inside its bucket loop: on lavapipe the list stays empty,
the implicit solvers' body-body contact never acts, and bodies pass into each other
(docs/benchmarks/STENCIL.md, "Every integrator on Vulkan against the CPU").
"""
import json
import sys

EXPECTED = {"in_loop": 400, "after_loop": 100, "never_taken_after_loop": 100}


def probe() -> dict:
    """The counters after one launch of each kernel on Vulkan (see EXPECTED)."""
    import numpy as np
    import taichi as ti

    ti.init(arch=ti.vulkan, offline_cache=False)
    if ti.lang.impl.current_cfg().arch != ti.vulkan:
        raise SystemExit("no Vulkan device here")
    bounds = ti.field(ti.i32, 8)
    count = ti.field(ti.i32, 3)
    bounds.from_numpy(np.arange(8, dtype=np.int32) * 2)

    @ti.kernel
    def counted():
        for _ in range(100):
            for _k in range(bounds[3], bounds[5]):  # 6 .. 9
                ti.atomic_add(count[0], 1)
            ti.atomic_add(count[1], 1)

    @ti.kernel
    def never_taken():
        for _ in range(100):
            for k in range(bounds[3], bounds[5]):
                if k < 0:
                    ti.atomic_add(count[0], 1)
            ti.atomic_add(count[2], 1)

    counted()
    never_taken()
    c = count.to_numpy()
    return {"in_loop": int(c[0]), "after_loop": int(c[1]), "never_taken_after_loop": int(c[2])}


if __name__ == "__main__":
    got = probe()
    print(json.dumps({"got": got, "expected": EXPECTED}))
    sys.exit(0 if got == EXPECTED else 1)
