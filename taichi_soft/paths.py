"""Where the package lies on disk: the one home of these paths (nothing else computes them)."""
from __future__ import annotations

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
# The folder holding the taichi_soft package: the checkout's root (main.py, scenes/, docs/) when
# run from a checkout, site-packages for an installed copy. Child processes (tasks, bench workers)
# start here, with it on their PYTHONPATH, so they import this same copy of the package.
ROOT = PACKAGE_DIR.parent
