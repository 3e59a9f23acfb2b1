"""cpu_threads: the workers of Taichi's CPU pool found, pinned one to a core while an explicit method
launches parallel steps and left free while an implicit solver does; nothing else pinned. Each case runs in a process
of its own (the pool is made at ti.init, and the placement outlives a test)."""
import json
import os
import subprocess
import sys

import pytest

from taichi_soft.paths import ROOT

# The placement and this probe are Linux's (sched_setaffinity, /proc/self/task).
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="thread placement is Linux only")

PROBE = """
import json, os, sys, threading
from taichi_soft import runtime
runtime.init("cpu", "f64", pin_threads=True, cpu_max_num_threads=int(sys.argv[1]))
every = set(os.sched_getaffinity(0))

def pinned():
    out = {}
    for name in os.listdir("/proc/self/task"):
        cores = os.sched_getaffinity(int(name))
        if cores != every:
            out[name] = sorted(cores)
    return out

from taichi_soft.sim.scene import load_scene
from taichi_soft.sim.simulation import Simulation

seen = {"cores": len(every), "at_start": pinned()}
for run in sys.argv[2:]:  # integrator:mode
    name, mode = run.split(":")
    Simulation(load_scene("plane", ["body.0.n=3"]), integrator=name, options={"mode": mode}).advance(1)
    seen[run] = pinned()
seen["main_free"] = os.sched_getaffinity(threading.get_native_id()) == every
print(json.dumps(seen))
"""


def _probe(threads: int, *integrators) -> dict:
    r = subprocess.run([sys.executable, "-c", PROBE, str(threads), *integrators], capture_output=True, text=True,
                       cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _one_core_each(pinned: dict) -> bool:
    return (len(pinned) == 2 and all(len(c) == 1 for c in pinned.values())
            and len({c[0] for c in pinned.values()}) == 2)


def test_the_two_workers_are_pinned_for_parallel_explicit_steps_only():
    """Nothing is pinned at start-up, nor for serial steps (the pool is not used); the first parallel
    explicit step finds the two workers and pins them, to different cores, nothing else; an implicit
    solver's parallel steps free them (its many short loops ran slower pinned), an explicit one's
    pins them again."""
    out = _probe(2, "semi_implicit_euler:serial", "semi_implicit_euler:parallel", "implicit_euler:parallel",
                 "rk4:parallel")
    assert out["main_free"], out
    assert out["at_start"] == {} and out["semi_implicit_euler:serial"] == {}, out
    if out["cores"] < 2:  # nothing to spread over: nothing pinned
        assert all(v == {} for k, v in out.items() if ":" in k), out
        return
    assert _one_core_each(out["semi_implicit_euler:parallel"]), out
    assert out["implicit_euler:parallel"] == {}, out
    assert out["rk4:parallel"] == out["semi_implicit_euler:parallel"], out


def test_a_one_thread_pool_is_left_alone():
    out = _probe(1, "semi_implicit_euler:parallel")
    assert out["semi_implicit_euler:parallel"] == {}, out
