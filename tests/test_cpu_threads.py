"""cpu_threads.pin_pool_workers: each worker of Taichi's CPU pool on its own core, nothing else
pinned. Each case runs in a process of its own (the pinning outlives the runtime's threads' work
and the pool is made at ti.init)."""
import json
import os
import subprocess
import sys

import pytest

from taichi_soft.paths import ROOT

# The pinning and this probe are Linux's (sched_setaffinity, /proc/self/task).
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="thread pinning is Linux only")

PROBE = """
import json, os, sys, threading
from taichi_soft import runtime
started = runtime.init("cpu", "f32", pin_threads=True, cpu_max_num_threads=int(sys.argv[1]))
every = set(os.sched_getaffinity(0))
pinned = {}
for name in os.listdir("/proc/self/task"):
    cores = os.sched_getaffinity(int(name))
    if cores != every:
        pinned[name] = sorted(cores)
print(json.dumps({"started": started["pinned_workers"], "pinned": pinned, "cores": len(every),
                  "main_free": os.sched_getaffinity(threading.get_native_id()) == every}))
"""


def _probe(threads: int) -> dict:
    r = subprocess.run([sys.executable, "-c", PROBE, str(threads)], capture_output=True, text=True, cwd=ROOT,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_a_two_thread_pool_gets_one_core_per_worker_and_the_rest_stays_free():
    out = _probe(2)
    assert out["main_free"]
    if out["cores"] < 2:  # nothing to spread over: nothing pinned
        assert out["started"] == 0 and out["pinned"] == {}
        return
    assert out["started"] == 2 and len(out["pinned"]) == 2  # the two workers, nothing else
    assert all(len(c) == 1 for c in out["pinned"].values())
    assert len({c[0] for c in out["pinned"].values()}) == 2  # on different cores


def test_a_one_thread_pool_is_left_alone():
    out = _probe(1)
    assert out["started"] == 0 and out["pinned"] == {}
