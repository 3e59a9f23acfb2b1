"""Progress bars on stderr, drawn by tqdm: on a terminal only (silent when stderr is piped).

``CountBar`` follows a count (frames of one run, configurations of the speed study);
``TaskBar`` follows a sweep of tasks (``taichi_soft.tasks``): done / running / failed and ETA.
"""
from __future__ import annotations

import sys

from tqdm import tqdm


class CountBar:
    """``CountBar(total, label)``; ``update(done, extra="")`` with the absolute count; ``close()``."""

    def __init__(self, total: int, label: str = "", unit: str = "it", enabled: bool | None = None):
        # disable=None: tqdm turns itself off when stderr is not a terminal
        self.bar = tqdm(total=max(int(total), 1), desc=label, unit=unit, file=sys.stderr, leave=True,
                        disable=None if enabled is None else not enabled, dynamic_ncols=True)

    def update(self, done: int, extra: str = "", total: int | None = None):
        if total is not None and total != self.bar.total:
            self.bar.total = max(int(total), 1)
        if extra:
            self.bar.set_postfix_str(extra, refresh=False)
        self.bar.update(done - self.bar.n)

    def close(self):
        self.bar.close()


class TaskBar:
    """A bar over a sweep's tasks; finished = done + failed, the postfix gives all three counts."""

    def __init__(self, total: int, label: str = "tasks", enabled: bool | None = None):
        self.bar = tqdm(total=total, desc=label, unit="task", file=sys.stderr, leave=True,
                        disable=None if enabled is None else not enabled, dynamic_ncols=True)

    def show(self, done: int, running: int, failed: int, advance: bool = False):
        self.bar.set_postfix_str(f"done {done}, running {running}, failed {failed}", refresh=False)
        self.bar.update(done + failed - self.bar.n)
        if not advance:
            self.bar.refresh()  # the running count changes without the bar moving

    def close(self, done: int, failed: int, interrupted: bool):
        if interrupted:
            self.bar.set_postfix_str(f"done {done}, failed {failed}, interrupted", refresh=False)
        self.bar.close()
