"""Writing output files safely: beside the destination first, then renamed into place.

A run that fails part-way never leaves a half-written file where the user's old one was.
Used by the command line and the renderer; physics never writes files.
"""
from __future__ import annotations

import os
import secrets
from pathlib import Path

from .errors import UserError


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
    raise UserError(f"cannot create a temporary file beside {path}")


def write_atomic(path: Path, write) -> None:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it over ``path``."""
    tmp = reserve_temp(path)
    try:
        write(str(tmp))
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
