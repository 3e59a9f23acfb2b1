"""Task functions for tests/test_tasks.py and tests/test_gallery.py: run by ``taichi_soft.tasks``
in a fresh process (the tests put this folder on PYTHONPATH). No Taichi: each costs one Python start."""
import os
import time
from pathlib import Path


def square(x):
    return x * x


def fail(message="deliberate failure"):
    raise RuntimeError(message)


def flaky(marker):
    """Fails on the first call (leaving ``marker``), succeeds on the second: exercises the retry."""
    p = Path(marker)
    if not p.exists():
        p.write_text(str(os.getpid()))
        raise RuntimeError("first attempt fails")
    return "second attempt"


def slow(seconds, marker, started=None):
    """Leaves ``started`` (if given), sleeps, then leaves ``marker``: a cancelled task never gets
    to write it."""
    if started:
        Path(started).write_text(str(os.getpid()))
    time.sleep(seconds)
    Path(marker).write_text("finished")
    return "slow"
