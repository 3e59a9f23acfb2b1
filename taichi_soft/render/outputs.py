"""Where frames go: video files, PNG folders, mesh folders, and the thread that writes them.

Every output is written beside its destination first and moved into place only by
``commit()``; ``abort()`` removes what was written. A run that fails part-way therefore never
leaves a half-written video or replaces the frames of an earlier run.
"""
from __future__ import annotations

import os
import queue
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import numpy as np

from ..errors import OutputError, UserError
from ..outfiles import fsync_file, reserve_dir, reserve_temp

VIDEO_SUFFIXES = (".mp4", ".gif")


class VideoFile:
    """An H.264 MP4 (yuv420p, which every player opens) or a GIF, encoded by ffmpeg as frames come.

    ``size`` = (width, height) in pixels; MP4 needs both even (checked by ``check_video_size``).
    ffmpeg (the binary imageio-ffmpeg ships) runs as our own child process so that its exit
    status is checked: an encoder error or a full disk raises ``OutputError`` at ``add`` or
    ``commit`` and the destination keeps its old file.
    """

    def __init__(self, path: Path, fps: float, size: tuple[int, int]):
        import imageio_ffmpeg

        self.path = Path(path)
        self.tmp = reserve_temp(self.path)
        if self.path.suffix.lower() == ".gif":
            # One palette for the whole clip (ffmpeg buffers the frames to build it): far better
            # colours than the fixed 8-bit palette GIF encoders use by default.
            encode = ["-vf", "split[a][b];[a]palettegen=stats_mode=full[p];[b][p]paletteuse=dither=bayer",
                      "-loop", "0", "-f", "gif"]
        else:
            # veryfast: encoding keeps up with rendering on two cores; crf 20 keeps thin lines and text sharp.
            encode = ["-vcodec", "libx264", "-pix_fmt", "yuv420p", "-preset", "veryfast", "-crf", "20",
                      "-movflags", "+faststart", "-f", "mp4"]
        self._log = tempfile.TemporaryFile()
        try:
            cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-v", "error", "-f", "rawvideo", "-pix_fmt", "rgb24",
                   "-s", f"{size[0]}x{size[1]}", "-r", f"{fps:.6g}", "-i", "-", "-an", *encode, str(self.tmp)]
            # Own session: a Ctrl-C or SIGTERM to the terminal's process group reaches us, not ffmpeg,
            # and we decide whether the file is finished or dropped.
            self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._log,
                                          start_new_session=True)
        except (OSError, RuntimeError) as e:  # no ffmpeg binary
            self.tmp.unlink(missing_ok=True)
            raise UserError(f"cannot start ffmpeg to write {self.path}: {e}") from None
        self.frames = 0

    def add(self, frame: np.ndarray, index: int):
        try:
            self._proc.stdin.write(np.ascontiguousarray(frame, dtype=np.uint8).tobytes())
        except OSError:  # ffmpeg exited: a full disk or an encoder error; its log says which
            self._proc.wait()
            raise OutputError(f"video {self.path} was not written: ffmpeg stopped: {self._ffmpeg_says()}") from None
        self.frames += 1

    def commit(self) -> Path:
        try:
            self._proc.stdin.close()
        except OSError:
            pass
        if self._proc.wait() != 0 or self.tmp.stat().st_size == 0:
            raise OutputError(f"video {self.path} was not written: ffmpeg failed: {self._ffmpeg_says()}")
        try:
            fsync_file(self.tmp)
        except OSError as e:
            raise OutputError(f"video {self.path} was not written: {e.strerror}") from None
        os.replace(self.tmp, self.path)
        return self.path

    def abort(self):
        if self._proc.poll() is None:
            self._proc.kill()
        self._proc.wait()
        self.tmp.unlink(missing_ok=True)

    def _ffmpeg_says(self) -> str:
        self._log.seek(0)
        lines = [ln.strip() for ln in self._log.read().decode(errors="replace").splitlines() if ln.strip()]
        return lines[-1] if lines else f"exit status {self._proc.returncode}"


class StagedDir:
    """Files named ``{prefix}_{index:05d}{suffix}`` collected in a hidden folder beside ``target``.

    ``commit`` moves them into ``target`` (created if needed) and deletes files of the same
    pattern left there by an earlier, longer run, so the folder holds exactly this run's files.
    Other files in ``target`` are never touched.
    """

    def __init__(self, target: Path, prefix: str, suffix: str):
        self.target, self.prefix, self.suffix = Path(target), prefix, suffix
        self.target.parent.mkdir(parents=True, exist_ok=True)
        self.staging = reserve_dir(self.target)

    def file(self, index: int) -> Path:
        return self.staging / f"{self.prefix}_{index:05d}{self.suffix}"

    def save(self, index: int, write) -> None:
        """``write(path)`` the file of ``index``; a failed write (full disk...) raises ``OutputError``."""
        path = self.file(index)
        try:
            write(path)
        except OSError as e:
            raise OutputError(f"{self.target} was not written: {path.name}: {e.strerror or e}") from None

    def commit(self) -> Path:
        self.target.mkdir(parents=True, exist_ok=True)
        written = set()
        for f in sorted(self.staging.iterdir()):
            os.replace(f, self.target / f.name)
            written.add(f.name)
        for old in self.target.glob(f"{self.prefix}_*{self.suffix}"):
            if old.name not in written:
                old.unlink()
        self.staging.rmdir()
        return self.target

    def abort(self):
        shutil.rmtree(self.staging, ignore_errors=True)


class PngFrames:
    """Numbered PNGs ``frame_00000.png`` ... in a folder."""

    def __init__(self, target: Path):
        self.dir = StagedDir(target, "frame", ".png")

    def add(self, frame: np.ndarray, index: int):
        from PIL import Image

        # compress_level 1: fast; PNG stays lossless
        self.dir.save(index, lambda path: Image.fromarray(frame).save(path, compress_level=1))

    def commit(self) -> Path:
        return self.dir.commit()

    def abort(self):
        self.dir.abort()


def open_image_sinks(video: Path | None, frames: Path | None, fps: float, size: tuple[int, int]) -> list:
    """The video file and/or PNG folder a run asked for, ready for ``add(image, index)``."""
    sinks = []
    try:
        if video:
            sinks.append(VideoFile(video, fps, size))
        if frames:
            sinks.append(PngFrames(frames))
    except BaseException:
        abort_all(sinks)
        raise
    return sinks


def commit_all(sinks) -> list[Path]:
    """Move every sink's output into place; returns the paths written.

    A sink that cannot be committed is aborted (its destination keeps the old output) and the
    others are still committed; then ``OutputError`` names every one that failed.
    """
    done, failed = [], []
    for sink in sinks:
        try:
            done.append(sink.commit())
        except (OutputError, OSError) as e:
            abort_all([sink])
            failed.append(str(e) if isinstance(e, OutputError) else f"{e.filename}: {e.strerror}")
    if failed:
        raise OutputError("; ".join(failed))
    return done


def abort_all(sinks):
    """Remove every sink's partial output; never raises."""
    for sink in sinks:
        try:
            sink.abort()
        except Exception:  # noqa: BLE001 - cleaning up after a failure already being reported
            pass


class FrameJob:
    """Base of a run that renders frames (``renderer``) and hands them to a ``writer`` (a
    ``BackgroundWriter``) for its ``output_sinks()``: ``finish()`` or ``abort()`` ends it, and
    either closes the renderer. Subclasses set the three and may override ``output_sinks``."""

    renderer = None
    writer = None
    sinks = ()

    def output_sinks(self) -> list:
        return self.sinks

    def finish(self) -> list[Path]:
        """Wait for the writer and move the outputs into place; returns the paths written."""
        try:
            self.writer.close()
            return commit_all(self.output_sinks())
        except BaseException:
            self.abort()
            raise
        finally:
            self._close_renderer()

    def abort(self):
        """Drop everything: no output file is created or replaced."""
        if self.writer is not None:
            self.writer.abort()
        abort_all(self.output_sinks())
        self._close_renderer()

    def _close_renderer(self):
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None


class BackgroundWriter:
    """Runs ``handle(item)`` for each submitted item, in order, on one worker thread.

    The queue holds at most ``maxsize`` items: the simulation only waits when encoding falls that
    far behind, and memory stays bounded. An exception in the worker is raised again in the
    caller at the next ``submit`` or at ``close``.
    """

    _STOP = object()

    def __init__(self, handle, maxsize: int = 4):
        self._handle = handle
        self._queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="taichi-soft-writer", daemon=True)
        self._thread.start()

    def _run(self):
        while True:
            item = self._queue.get()
            if item is self._STOP:
                return
            if isinstance(item, threading.Event):  # flush(): everything before it is written
                item.set()
                continue
            if self._error is None:
                try:
                    self._handle(item)
                except BaseException as e:  # noqa: BLE001 - handed to the caller
                    self._error = e

    def submit(self, item):
        while True:
            self._raise_if_failed()
            try:
                self._queue.put(item, timeout=0.2)  # wake up now and then to notice a dead worker
                return
            except queue.Full:
                continue

    def flush(self):
        """Wait until everything submitted so far is written (the worker keeps running); re-raise
        a worker failure."""
        done = threading.Event()
        self.submit(done)
        while not done.wait(0.2):
            self._raise_if_failed()
        self._raise_if_failed()

    def _raise_if_failed(self):
        if self._error is not None:
            raise self._error

    def close(self):
        """Wait until everything submitted is written; re-raise a worker failure."""
        self._queue.put(self._STOP)
        self._thread.join()
        self._raise_if_failed()

    def abort(self):
        """Stop without finishing the backlog."""
        self._error = self._error or RuntimeError("aborted")
        try:
            while True:
                self._queue.get_nowait()
        except queue.Empty:
            pass
        self._queue.put(self._STOP)
        self._thread.join()


def check_video_size(path: Path | None, width: int, height: int):
    """MP4 (H.264 in yuv420p) stores colour at half resolution: width and height must be even."""
    if path is not None and path.suffix.lower() == ".mp4" and (width % 2 or height % 2):
        raise UserError(f"--video {path}: MP4 needs an even width and height, got {width}x{height}; "
                        f"try {width + width % 2}x{height + height % 2}")
