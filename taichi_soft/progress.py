"""A dependency-free progress bar on stderr: drawn on a terminal, silent when piped."""
from __future__ import annotations

import sys
import time


class Progress:
    """``Progress(total, label)``; call ``update(done, extra="")`` and ``close()``."""

    def __init__(self, total: int, label: str = "", stream=None, enabled: bool | None = None):
        self.total = max(int(total), 1)
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.start = time.perf_counter()
        self._last_draw = 0.0

    def update(self, done: int, extra: str = "", force: bool = False):
        if not self.enabled:
            return
        now = time.perf_counter()
        if not force and now - self._last_draw < 0.1 and done < self.total:
            return
        self._last_draw = now
        frac = min(done / self.total, 1.0)
        elapsed = now - self.start
        eta = elapsed / frac - elapsed if frac > 0 else float("nan")
        width = 28
        bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
        eta_text = f"ETA {eta:5.1f}s" if eta == eta else "ETA   ?  "
        self.stream.write(f"\r{self.label} [{bar}] {100 * frac:5.1f}% {extra} {eta_text} ")
        self.stream.flush()

    def close(self):
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()
