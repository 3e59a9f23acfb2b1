"""Shared fixtures: one Taichi runtime per test session (CPU, f64), scene helpers, CLI runner."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# The suite is dominated by compiling kernels (each Simulation compiles its own): without Taichi's
# IR optimisation passes the implicit solvers compile about 5x faster and the tests' small cubes run
# about as fast (taichi_soft/runtime.py, OPTIMIZE_ENV). Set before anything starts Taichi, so the
# command-line runs the tests start in child processes inherit it.
os.environ.setdefault("TAICHI_SOFT_OPTIMIZE", "0")


@pytest.fixture(scope="module", autouse=True)
def taichi_runtime():
    """A fresh CPU f64 Taichi runtime for each test module (a module may override this fixture to
    start another precision); ``fresh_taichi`` starts it again before each test.

    Every field allocated after a kernel has run opens a new Taichi SNode tree, and a runtime
    holds a bounded number of them (Taichi 1.7 crashes past the limit); re-initialising frees them all.
    """
    from taichi_soft import runtime

    return runtime.init("cpu", "f64")


@pytest.fixture(autouse=True)
def fresh_taichi(request, taichi_runtime):
    """Start the module's Taichi runtime again before each test that follows one that used it,
    unless the module is marked ``taichi_shared``.

    Why: Taichi's kernel cache key names each field by its SNode id, and ids count from zero in
    each runtime. A test that builds the same simulation as an earlier one, in any process, on a
    runtime started afresh allocates the same ids and loads that test's compiled kernels from
    ~/.cache/taichi instead of compiling them again; in one long-lived runtime every new object has
    new ids, so nothing it compiles is found again (docs/decisions/fresh-runtime-per-test.md).

    A module whose fixtures or module-level caches keep Taichi fields or kernels from one test to
    the next must be marked ``pytestmark = pytest.mark.taichi_shared``: a field used after its
    runtime was started again is a segmentation fault, not an error.
    """
    if request.node.get_closest_marker("taichi_shared") is not None:
        return
    from taichi.lang import impl

    rt = impl.get_runtime()
    if rt.materialized or rt.global_vars:
        restart_taichi(taichi_runtime)


def restart_taichi(started: dict):
    """Start Taichi again as ``started`` (what ``runtime.init`` returned) says: its arch, precision,
    fast math and optimisation."""
    from taichi_soft import runtime

    runtime.init(started["arch"], started["precision"], fast_math=started["fast_math"],
                 optimize=started["optimize"])


@pytest.fixture
def make_sim():
    """``make_sim(scene="plane", sets=[...], **sim_kwargs)`` -> a ``Simulation``."""
    from taichi_soft.sim.integrators import names
    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import Simulation

    def make(scene="plane", sets=(), **kwargs):
        return Simulation(load_scene(scene, list(sets), integrator_names=names()), **kwargs)

    return make


# A tool the suite needs (Xvfb, a Vulkan device for GGUI, root for a small tmpfs) that is missing
# fails the test: scripts/setup.sh installs them, so a skip would hide a broken set-up and every check
# behind it. Set TAICHI_SOFT_ALLOW_MISSING_TOOLS=1 to skip those tests instead (said per test).
ALLOW_MISSING_ENV = "TAICHI_SOFT_ALLOW_MISSING_TOOLS"


def missing_tool(reason: str):
    """Fail (default) or, with TAICHI_SOFT_ALLOW_MISSING_TOOLS=1, skip: a tool the test needs is missing."""
    if os.environ.get(ALLOW_MISSING_ENV) == "1":
        pytest.skip(reason)
    pytest.fail(f"{reason}; run scripts/setup.sh, or set {ALLOW_MISSING_ENV}=1 to skip such tests", pytrace=False)


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` is running: it exists and is not a zombie waiting to be reaped."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def run_cli(*args, cwd=ROOT, timeout=600):
    """Run ``python main.py ARGS`` in a subprocess; returns the CompletedProcess (text)."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.run([sys.executable, str(ROOT / "main.py"), *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def cli():
    return run_cli
