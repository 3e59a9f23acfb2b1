"""Screenshots and MP4 recordings of the demo window (ImGui panels included).

A recording is written in wall-clock time: each displayed frame is repeated (or skipped) so the
video plays at the speed the class saw, whatever the window's frame rate was. Encoding runs on
the renderer's writer thread (``render.outputs``), so recording barely slows the window.
"""
from __future__ import annotations

import time
from datetime import datetime
from pathlib import Path

from ..render.outputs import BackgroundWriter, VideoFile
from ..render.window import window_rgb

VIDEO_FPS = 30
MAX_REPEAT = 15  # frames one displayed frame may fill (a stall longer than 0.5 s is not padded)


def default_path(kind: str, scene: str, suffix: str, folder: str = "out") -> Path:
    """``out/demo-<scene>-<kind>-<YYYYmmdd-HHMMSS>[-<k>]<suffix>``, a name not taken yet (two
    screenshots in one second must not overwrite each other); the folder is created."""
    Path(folder).mkdir(parents=True, exist_ok=True)
    stem = f"demo-{scene}-{kind}-{datetime.now():%Y%m%d-%H%M%S}"
    path, k = Path(folder) / f"{stem}{suffix}", 1
    while path.exists():
        k += 1
        path = Path(folder) / f"{stem}-{k}{suffix}"
    return path


class Recording:
    """An MP4 of the window being written; ``add(window)`` every frame, then ``stop()``."""

    def __init__(self, path: Path, size: tuple[int, int], fps: int = VIDEO_FPS, clock=time.perf_counter):
        self.path = Path(path)
        # H.264 in yuv420p needs even sizes: an odd last row or column is cropped.
        self.size = (size[0] - size[0] % 2, size[1] - size[1] % 2)
        self.fps, self.clock = fps, clock
        self.video = VideoFile(self.path, fps, self.size)
        self.writer = BackgroundWriter(lambda item: self.video.add(*item))
        self.start = None
        self.frames = 0

    def add(self, window):
        now = self.clock()
        if self.start is None:
            self.start = now
        due = int((now - self.start) * self.fps) + 1
        repeat = min(due - self.frames, MAX_REPEAT)
        if repeat <= 0:
            return
        image = window_rgb(window)[: self.size[1], : self.size[0]]
        for _ in range(repeat):
            self.writer.submit((image, self.frames))
            self.frames += 1
        self.frames = max(self.frames, due)

    def stop(self) -> Path:
        """Finish encoding and move the file into place; returns its path."""
        try:
            self.writer.close()
            return self.video.commit()
        except BaseException:
            self.video.abort()
            raise
