"""Taichi start-up: backend and precision are chosen here, never at import time."""
from __future__ import annotations

import contextlib
import io
import os

# Taichi's start-up environment (no banner, errors only) is set in taichi_soft/__init__.py, which
# runs before any module of the package imports Taichi.
import taichi as ti

from . import compile_speed, cpu_threads
from .errors import UserError

ARCHS = ("cpu", "cuda", "vulkan", "metal", "auto")
PRECISIONS = ("f32", "f64")

_current: dict | None = None


# Fast math lets the compiler reassociate, contract multiply-adds into FMA and assume no NaN or
# inf. On Taichi 1.7's CPU backend it changes little (measured 0.96-1.06x per CPU second; in the
# x86 code only the FMA contraction shows, square roots and divisions stay exact); GPU backends
# were not measured (no GPU lent). The command line turns it on for run, compare and demo
# (FAST_MATH_CLI_DEFAULT): it was never measured slower, results differ from IEEE arithmetic at
# the rounding level only (tests/test_fast_math.py), and the divergence check reads NaN/inf from
# the bits, which fast math cannot optimise away. Library callers (the tests, the accuracy and
# stability studies) get it off unless they ask: convergence-order fits and the tiny-step
# reference solutions compare errors down to 1e-12 m, where every rounding must be IEEE's.
FAST_MATH_CLI_DEFAULT = True

# The command line's processes pin each worker of Taichi's CPU thread pool to its own core while an
# explicit method steps (cpu_threads.py: unpinned, the 2-core VM ran two-thread explicit steps at
# n = 40 barely faster than one thread; the implicit solvers ran slower pinned). Library callers (the
# tests) leave them free unless they ask: finding the workers takes a 0.1-s loop, once per process
# that launches parallel explicit steps.
PIN_THREADS_CLI_DEFAULT = True

# Taichi's own IR passes (``advanced_optimization``) are most of a kernel's compile time. Runs are
# optimised by default (the speed studies measure what users get); ``TAICHI_SOFT_OPTIMIZE=0`` turns
# the passes off for work dominated by compiling: the test suite (tests/conftest.py sets it, child
# processes inherit it) and short experiments. Measured 2026-12-06 on the 2-core Intel Xeon VM,
# default cube on the plane, cold cache, with the passes (less the CFG one, below) / without them:
# implicit_euler compiles in 3.4 / 1.9 s of CPU and steps 1.25x slower without, fast_mass_spring
# 9.3 / 3.9 s and 1.29x slower (75 steps at 1/30 s, one run each on a busy machine).
OPTIMIZE_ENV = "TAICHI_SOFT_OPTIMIZE"

# Of those passes, the control-flow-graph one (store-to-load forwarding and dead-store elimination
# over the whole kernel) grows faster than the kernel (Taichi issue #1785), and the implicit solvers'
# one-launch step is one large kernel. Measured 2026-12-06 on the 2-core Intel Xeon VM, default cube
# on the plane, f64, cold cache, CPU seconds to compile (first step) with / without it:
# implicit_euler 18.7 / 3.2, fast_mass_spring 64.7 / 11.4, rk4 0.88 / 0.57, semi-implicit Euler
# 0.42 / 0.30; steps/s without it against with it (3 rounds, interleaved processes, medians),
# implicit_euler 1.06x, fast_mass_spring 1.16x, rk4 n = 10 / 40 1.15x / 0.93x, semi-implicit Euler
# f64 n = 10 / 40 0.99x / 0.94x, f32 with fast math n = 10 0.99x (rounds on this VM differ by up
# to 30 %); at one thread beside one other busy process, f32, fast math, n = 40, no terrain, 4 rounds:
# 1.02x. No slowdown beyond the noise; and bit-identical states and solver statistics with fast
# math off (scripts/same_answers.py --stats, TAICHI_SOFT_OPTIMIZE=1; with fast math on they may
# differ at rounding level, as fast math allows). So optimised runs skip that pass.
SKIP_CFG_PASS = True

# Taichi's loop-invariant caching of global loads (``cache_loop_invariant_global_vars``) reads stale
# values where a loop also writes them through another access: upstream issues #8576 and #8578, open
# for 1.7.4. It hit us in the implicit solvers' one-launch step: a whole-vector read after atomics on
# the components returned the step's first values, so a rebuilt pair list was sized for the wrong
# moves and missed pairs in contact (scripts/taichi_stale_vector_read.py). With the pass
# off that script reads right. Measured 2026-12-07 on the 2-core Intel Xeon VM, steps/s with the pass
# on / off, two rounds of one process per run, alternating: semi-implicit Euler f32 n = 10 serial
# 10068 / 9981 and 9860 / 10363, n = 40 parallel 258 / 258 and 243 / 274; RK4 n = 10 2630 / 2569
# and 2515 / 2474; implicit_euler default cube 192 / 197 and 183 / 176; fast_mass_spring pile 125 /
# 124 and 122 / 120: no difference beyond the noise. Off on every backend (on a GPU not measured).
CACHE_LOOP_INVARIANTS = False
# Taichi's offline cache does not key kernels by that option: a kernel cached with the pass on was
# loaded with it off and read stale all the same (measured with the script above, 2026-12-07). So the
# kernels compiled with it off live in a cache directory of their own, beside Taichi's (the user's
# TI_OFFLINE_CACHE_FILE_PATH, else Taichi's default, taken before any ti.init changes it).
NO_LOOP_INVARIANT_SUFFIX = "-no-loop-invariants"
_TAICHI_CACHE_DIR = os.environ.get("TI_OFFLINE_CACHE_FILE_PATH") or ti.lang.impl.default_cfg().offline_cache_file_path

# Taichi's offline kernel cache (~/.cache/taichi) evicts its least recently used quarter whenever it
# passes 100 MiB, checked as each process exits. The kernels of every integrator, terrain and
# precision take more than that (the test suite leaves 115 MiB), so at the default every process
# exit evicted kernels the next process compiled again: measured 2026-12-06 on the 2-core VM, the
# by_stiffness test took 31 s in a suite run against 13 s with its kernels cached. At 1 GiB the
# cache held 339 MiB after one suite run and 457 MiB after two, with nothing evicted. Any process
# that starts Taichi at the default limit evicts, even with ``offline_cache=False`` (measured
# 2026-12-06: 4956 cache files to 3718 after a bare ``ti.init``), so every process of the project,
# the tests' probes included, starts Taichi through ``init``.
KERNEL_CACHE_BYTES = 1 << 30


def optimize_default() -> bool:
    """Whether Taichi's IR optimisation passes run: on unless ``TAICHI_SOFT_OPTIMIZE=0``."""
    value = os.environ.get(OPTIMIZE_ENV, "1").strip().lower()
    if value not in ("0", "1", "false", "true", "off", "on"):
        raise UserError(f"{OPTIMIZE_ENV}={value!r}: use 1 (optimise kernels, the default) or 0 (compile faster)")
    return value in ("1", "true", "on")


def init(arch: str = "cpu", precision: str = "f64", fast_math: bool = False, optimize: bool | None = None,
         pin_threads: bool = False, **kwargs) -> dict:
    """Initialise Taichi on ``arch`` with default float ``precision``; returns what was started.

    ``fast_math``: let the compiler use fast floating-point arithmetic (see FAST_MATH_CLI_DEFAULT).
    ``optimize``: run Taichi's IR optimisation passes (None: ``optimize_default()``, see OPTIMIZE_ENV).
    ``pin_threads``: on the CPU, pin each worker of Taichi's thread pool to its own core while an
    integrator that wants it launches parallel steps (``cpu_threads``; see PIN_THREADS_CLI_DEFAULT).
    Raises ``UserError`` if the backend is unknown or not available here (Taichi would silently
    fall back to the CPU), or if the backend cannot do f64.
    """
    global _current
    if arch not in ARCHS:
        raise UserError(f"unknown backend {arch!r}; choose one of: {', '.join(ARCHS)}")
    if precision not in PRECISIONS:
        raise UserError(f"unknown precision {precision!r}; choose one of: {', '.join(PRECISIONS)}")
    ti_arch = {"cpu": ti.cpu, "cuda": ti.cuda, "vulkan": ti.vulkan, "metal": ti.metal, "auto": ti.gpu}[arch]
    if arch == "auto":
        # Prefer a GPU, quietly fall back to the CPU.
        ti_arch = ti.gpu
    optimize = optimize_default() if optimize is None else bool(optimize)
    compile_speed.install()
    options = dict(fast_math=bool(fast_math), offline_cache=True, advanced_optimization=optimize,
                   offline_cache_max_size_of_files=KERNEL_CACHE_BYTES)
    if optimize and SKIP_CFG_PASS:
        options["cfg_optimization"] = False
    options["cache_loop_invariant_global_vars"] = CACHE_LOOP_INVARIANTS
    options.update(kwargs)
    if not options["cache_loop_invariant_global_vars"] and "offline_cache_file_path" not in kwargs:
        options["offline_cache_file_path"] = _TAICHI_CACHE_DIR.rstrip(os.sep) + NO_LOOP_INVARIANT_SUFFIX
    # ti.init prints a "Starting on arch" banner to stdout; keep stdout for our own output.
    with contextlib.redirect_stdout(io.StringIO()):
        ti.init(arch=ti_arch, default_fp=ti.f64 if precision == "f64" else ti.f32, **options)
    started = ti.lang.impl.current_cfg().arch
    name = _arch_name(started)
    if arch not in ("auto", "cpu") and name != arch:
        ti.reset()
        raise UserError(f"backend {arch!r} is not available on this machine; use --arch cpu or --arch auto")
    if precision == "f64" and name in ("vulkan", "metal"):
        ti.reset()
        raise UserError(f"backend {name!r} has no f64 support here; use --precision f32")
    cpu_threads.want_pinning(pin_threads and name == "cpu")
    _current = {"arch": name, "precision": precision, "fast_math": bool(fast_math), "optimize": optimize}
    return dict(_current)


@contextlib.contextmanager
def ir_passes(on: bool):
    """Kernels compiled inside run Taichi's IR optimisation passes only if ``on`` and the runtime
    runs them (``init``'s ``optimize``). The offline cache keys kernels by this option, so a kernel
    compiled either way is found again only the same way."""
    cfg = ti.lang.impl.current_cfg()
    before = cfg.advanced_optimization
    cfg.advanced_optimization = before and on
    try:
        yield
    finally:
        cfg.advanced_optimization = before


def current() -> dict | None:
    """The backend, precision and fast-math setting of the running Taichi, or None before ``init``."""
    return None if _current is None else dict(_current)


def _arch_name(a) -> str:
    for name, value in (("cpu", ti.x64), ("cpu", ti.arm64), ("cuda", ti.cuda), ("vulkan", ti.vulkan), ("metal", ti.metal)):
        if a == value:
            return name
    return str(a)


def available_archs() -> list[str]:
    """Backends this machine can run, by asking Taichi (cpu is always there)."""
    found = ["cpu"]
    for name, a in (("cuda", ti.cuda), ("vulkan", ti.vulkan), ("metal", ti.metal)):
        try:
            if ti.lang.misc.is_arch_supported(a):
                found.append(name)
        except Exception:  # noqa: BLE001 - probing must never crash `list`
            pass
    return found
