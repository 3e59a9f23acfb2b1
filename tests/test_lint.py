"""The tree is lint-clean under the project's ruff rules (pyproject.toml, [tool.ruff]). ruff is a
pinned requirement, so a missing ruff fails here instead of passing unchecked."""
import subprocess
import sys

from taichi_soft.paths import ROOT


def test_ruff_finds_nothing():
    done = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(ROOT)],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-1000:]
