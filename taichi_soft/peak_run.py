"""The memory study's task (``bench/memory.py``): the CLI's own command in this process, then the
process's peak memory. It sits at the CLI's layer because it runs the CLI, two layers above the
studies: ``bench.memory`` names it only as a task's ``"module:function"`` string, run in a fresh
process.
"""
from __future__ import annotations

import os
import subprocess


def peak_of_run(argv: list[str], arch: str) -> dict:
    """A task (tasks.py), so in a fresh process: the CLI's own ``argv``, then this process's peak
    resident bytes (VmHWM) and, on CUDA, the device bytes nvidia-smi shows for it."""
    import contextlib
    import resource

    from .cli import main

    with open(os.devnull, "w") as null, contextlib.redirect_stdout(null):
        rc = main(argv)
    try:
        with open("/proc/self/status") as f:
            peak = next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmHWM:"))
    except (OSError, StopIteration):
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    device = None
    if arch == "cuda":
        try:
            q = subprocess.run(["nvidia-smi", "--query-compute-apps=pid,used_memory", "--format=csv,noheader,nounits"],
                               capture_output=True, text=True, timeout=20).stdout
            device = sum(int(ln.split(",")[1]) for ln in q.splitlines()
                         if ln.split(",")[0].strip() == str(os.getpid())) * 2**20
        except (OSError, ValueError, IndexError, subprocess.SubprocessError):
            device = None
    return {"rc": rc, "peak_bytes": peak, "device_bytes": device}
