"""A Taichi 1.7.4 fault, reduced from the implicit pair list (pair_list._collect): inside a
serialized loop, a whole-vector read of two 0-D vector fields just after atomics on their components
returns the values of the first pass, when the IR passes are on (``advanced_optimization``).

    .venv/bin/python scripts/taichi_stale_vector_read.py     # both settings; exit 1 if a read is stale
    .venv/bin/python scripts/taichi_stale_vector_read.py --project   # as taichi_soft.runtime starts
                                                                     # Taichi (optimised): exit 0 if right

Measured 2026-12-07 on the 2-core Intel Xeon VM (CPU backend, f64): optimised, every pass read the
first pass's width, [4, 4, 4, 4]; unoptimised [4, 40, 400, 4000], as expected. The same code with
one field (atomic_min only), straight-line instead of in an inner loop, or not serialized, read
right; so did the optimised kernel with the pass ``cache_loop_invariant_global_vars`` off (Taichi
issues #8576, #8578). The project turns that pass off (``runtime.CACHE_LOOP_INVARIANTS``) and reads
such values a component at a time; tests/test_body_contact_implicit.py runs ``--project``.
"""
import json
import subprocess
import sys
from pathlib import Path

EXPECTED = [4.0, 40.0, 400.0, 4000.0]  # the path's x extent, times 10 per pass


def probe(optimise: bool, project: bool = False) -> list:
    """The widths read in each pass, with Taichi's IR passes on or off, or (``project``) with Taichi
    started by ``taichi_soft.runtime.init``, optimised (run in a fresh process)."""
    import numpy as np
    import taichi as ti

    if project:
        sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
        from taichi_soft import runtime

        runtime.init("cpu", "f64", optimize=True)
    else:
        ti.init(arch=ti.cpu, default_fp=ti.f64, offline_cache=False, advanced_optimization=optimise)
    n = 4
    path = ti.Vector.field(3, float, n)
    d_lo = ti.Vector.field(3, float, ())
    d_hi = ti.Vector.field(3, float, ())
    width = ti.field(float, 4)

    @ti.func
    def measure(k):
        for c in ti.static(range(3)):
            d_lo[None][c] = 1e30
            d_hi[None][c] = -1e30
        for i in range(n):
            for c in ti.static(range(3)):
                ti.atomic_min(d_lo[None][c], path[i][c])
                ti.atomic_max(d_hi[None][c], path[i][c])
        width[k] = (d_hi[None] - d_lo[None]).x  # the whole-vector read

    @ti.kernel
    def run():
        ti.loop_config(serialize=True)
        for _ in range(1):
            measure(0)
            for it in range(3):
                for i in range(n):
                    path[i] = path[i] * 10.0
                measure(1 + it)

    path.from_numpy(np.array([[3.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [5.0, 0, 0]]))
    run()
    return width.to_numpy().tolist()


def _widths(*args: str) -> list:
    """``probe``'s widths from a fresh process (each Taichi setting needs its own ti.init)."""
    r = subprocess.run([sys.executable, __file__, "--probe", *args], capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> int:
    if sys.argv[1:2] == ["--probe"]:
        print(json.dumps(probe(sys.argv[2] == "1", project=sys.argv[3:] == ["project"])))
        return 0
    if sys.argv[1:2] == ["--project"]:
        got = _widths("1", "project")
        print(f"taichi_soft.runtime (optimised): widths {got}, expected {EXPECTED}")
        return 0 if got == EXPECTED else 1
    stale = False
    for optimise in ("1", "0"):
        got = _widths(optimise)
        print(f"advanced_optimization={optimise == '1'}: widths {got}, expected {EXPECTED}")
        stale |= got != EXPECTED
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
