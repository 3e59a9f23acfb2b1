"""Taichi start-up: backend and precision are chosen here, never at import time."""
from __future__ import annotations

import contextlib
import io
import os

# Taichi's start-up environment (no banner, errors only) is set in taichi_soft/__init__.py, which
# runs before any module of the package imports Taichi.
import taichi as ti

from .workarounds import compile_speed, cpu_threads
from .errors import UserError

ARCHS = ("cpu", "cuda", "vulkan", "metal", "auto")
PRECISIONS = ("f32", "f64")

_current: dict | None = None


# Fast math on for run/compare/demo, off for library callers, whose error fits need IEEE rounding
# (docs/decisions/fast-math-on-the-command-line.md).
FAST_MATH_CLI_DEFAULT = True

# The command line pins each CPU pool worker to its own core while explicit methods step; library
# callers leave them free unless they ask (docs/decisions/thread-pinning.md).
PIN_THREADS_CLI_DEFAULT = True

# Taichi's IR passes are most of a compile: runs keep them, TAICHI_SOFT_OPTIMIZE=0 (the test suite,
# short experiments) turns them off (docs/decisions/ir-passes-off-in-tests.md).
OPTIMIZE_ENV = "TAICHI_SOFT_OPTIMIZE"

# The CFG pass grows faster than the kernel (Taichi #1785) and buys no speed here: optimised runs
# skip it (docs/decisions/skip-the-cfg-pass.md).
SKIP_CFG_PASS = True

# Taichi's loop-invariant caching of global loads reads stale values (Taichi #8576, #8578, open for
# 1.7.4; scripts/taichi_stale_vector_read.py): off everywhere (docs/decisions/loop-invariant-cache-off.md).
CACHE_LOOP_INVARIANTS = False
# Taichi's offline cache does not key kernels by that option, so kernels compiled with it off live in
# a cache directory of their own beside Taichi's (the user's TI_OFFLINE_CACHE_FILE_PATH, else Taichi's
# default, taken before any ti.init changes it).
NO_LOOP_INVARIANT_SUFFIX = "-no-loop-invariants"
_TAICHI_CACHE_DIR = os.environ.get("TI_OFFLINE_CACHE_FILE_PATH") or ti.lang.impl.default_cfg().offline_cache_file_path

# Taichi's offline cache evicts a quarter past 100 MiB, and our kernels take more: every process
# of the project starts Taichi through ``init`` with this limit (docs/decisions/kernel-cache-size.md).
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
