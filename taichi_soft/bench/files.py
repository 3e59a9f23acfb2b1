"""Writing a study's files: CSV rows and text, each written atomically (``outfiles``)."""
from __future__ import annotations

import csv
from pathlib import Path

from ..outfiles import write_atomic


def write_csv(rows: list[dict], path: Path):
    """Rows as CSV (columns: every key, in first-seen order), written atomically."""
    keys = list(dict.fromkeys(k for r in rows for k in r))

    def write(tmp):
        with open(tmp, "w", newline="") as f:
            if not rows:
                return
            w = csv.DictWriter(f, fieldnames=keys)
            w.writeheader()
            for r in rows:
                w.writerow({k: r.get(k) for k in keys})
    write_atomic(Path(path), write)


def write_text(path: Path, text: str):
    """A text file written atomically (a full disk or a kill never leaves half of it)."""
    write_atomic(Path(path), lambda tmp: Path(tmp).write_text(text))
