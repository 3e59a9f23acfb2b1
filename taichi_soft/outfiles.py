"""Writing output files safely: beside the destination first, then renamed into place.

A run that fails part-way never leaves a half-written file where the user's old one was.
Used by the command line and the renderer; physics never writes files.
"""
from __future__ import annotations

import os
import secrets
from pathlib import Path

from .errors import OutputError


def reserve_temp(path: Path) -> Path:
    """A new empty file beside ``path`` with the same suffix (ffmpeg picks the format by it).

    Created with the usual permissions (0666 less the umask), unlike ``tempfile.mkstemp``'s 0600,
    because it becomes the user's file.
    """
    for _ in range(100):
        tmp = path.with_name(f".{path.stem}.{os.getpid()}.{secrets.token_hex(4)}{path.suffix}")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            continue
    raise OutputError(f"cannot create a temporary file beside {path}")


def write_atomic(path: Path, write) -> None:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, flush it to disk, then rename
    it over ``path``. A failed write (full disk, ...) raises ``OutputError``; ``path`` is untouched."""
    tmp = reserve_temp(path)
    try:
        write(str(tmp))
        fsync_file(tmp)
        os.replace(tmp, path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"{path} was not written: {e.strerror or e}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def fsync_file(path: Path) -> None:
    """Force ``path``'s data to disk, so a full disk shows up here and not after the rename."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def probe_writable(directory: Path) -> None:
    """Create and remove a file in ``directory``: the only sure test that an output can go there
    (``os.access`` says yes for root in /proc and /sys). Raises ``OSError`` if not."""
    tmp = reserve_temp(directory / "probe.tmp")
    tmp.unlink()
