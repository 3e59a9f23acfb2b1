"""``python main.py bench accuracy|stability|speed|memory|report``: measure, then write CSV, PNG and Markdown.

Each study returns plain rows (dicts); ``write_*`` functions turn rows into files. ``report``
runs all four and writes ``REPORT.md`` beside the CSVs and plots: ``write_report`` (this module)
puts together the Markdown sections of ``report_markdown``. The studies run in ``sweeps``
(accuracy, precision, stability: tasks) and ``serial_studies`` (speed, memory); the files are
written by ``files``. ``quick`` shrinks every study (tiny cubes, few steps) so the whole report
runs in a few minutes on 2 cores; its numbers check the machinery, not the physics at full size.

The accuracy and stability sweeps are independent runs dispatched as tasks
(``taichi_soft.tasks``: each in a fresh process, ``--workers N`` local processes or a Dask
``--scheduler``); their wall-time columns are measured under whatever else runs at the same time,
so publish timings from ``--workers 1`` on a quiet machine. The speed and memory studies always run serially,
one configuration at a time, for the same reason. A sweep interrupted with Ctrl-C stops and still
writes what it measured, marked as interrupted; a task that failed twice is listed as failed.
"""
from __future__ import annotations

from pathlib import Path

from ..tasks import RETRIES
from . import machine
from .files import write_text
from .report_markdown import accuracy_markdown, speed_markdown, stability_markdown


def write_report(out_dir: Path, command: str, acc: dict | None, stab: dict | None, speed: dict | None,
                 seconds: float, mem: dict | None = None, name: str = "REPORT.md", prec: dict | None = None) -> Path:
    """The Markdown report of the studies given, as ``out_dir / name`` (``bench speed`` writes
    SPEED.md: a single study never replaces the full REPORT.md)."""
    info = machine.describe()
    parts = ["# taichi-soft benchmark report", "",
             f"Command: `{command}` ({seconds / 60:.1f} min)", "", "Machine:", "", machine.markdown(info)]
    if any(r and r.get("interrupted") for r in (acc, stab, speed, mem, prec)):
        parts += ["**Interrupted (Ctrl-C): the tables hold what was measured before the stop.**", ""]
    failed = {k: v for r in (acc, stab, prec) if r for k, v in r.get("failed", {}).items()}
    if failed:
        parts += [f"**Failed tasks (each submitted {RETRIES + 1} times): their rows are missing from the tables.**", ""]
        parts += [f"* `{k}`: {v[:300]}" for k, v in failed.items()] + [""]
    if acc:
        parts.append(accuracy_markdown(acc))
    if prec:
        from .verdict import markdown as precision_markdown

        parts.append(precision_markdown(prec))
    if stab:
        parts.append(stability_markdown(stab))
    if speed:
        parts.append(speed_markdown(speed))
    if mem:
        from .memory import markdown as memory_markdown

        parts.append(memory_markdown(mem))
    path = out_dir / name
    write_text(path, "\n".join(parts) + "\n")
    return path
