"""Writing output files safely: beside the destination first, then renamed into place.

A run that fails part-way never leaves a half-written file where the user's old one was.
Used by the command line and the renderer; physics never writes files.
"""
from __future__ import annotations

import math
import os
import re
import secrets
import shutil
from pathlib import Path

from .errors import OutputError, raise_if_interrupted


def reserve_dir(path: Path) -> Path:
    """A new empty hidden folder beside ``path``, named as ``reserve_temp`` names files (with the pid)."""
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}")
        try:
            tmp.mkdir()
            return tmp
        except FileExistsError:
            continue
    raise OutputError(f"cannot create a temporary folder beside {path}")


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
        raise_if_interrupted()  # a signal whose exception was swallowed: keep the old output
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


# Hidden temporaries are named ``.{stem}.{pid}.{hex}{suffix}`` (files, ``reserve_temp``) and
# ``.{name}.{pid}.{hex}`` (staging folders): the pid says whose they are.
_TEMP = re.compile(r"\.(?P<base>.+)\.(?P<pid>\d+)\.(?P<hex>[0-9a-f]{8})(?P<suffix>(\.[^.]*)?)")


def temp_owner(name: str) -> int | None:
    """The id of the process named in a hidden temporary's file ``name``, or None for any other name."""
    m = _TEMP.fullmatch(name)
    return int(m["pid"]) if m else None


def _running(pid: int) -> bool:
    """Whether a process ``pid`` exists on this machine (one of another user's counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temps(path: Path, inside: bool = False) -> list[str]:
    """Remove the hidden temporaries a killed run (SIGKILL, power loss) left beside ``path`` -- those
    of ``path`` itself and write probes of its folder -- and, with ``inside`` (``path`` an output
    folder), every one inside it, if the process named in them is gone. Returns one line per
    removal, to be said to the user. A live run's temporaries are left alone."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    said = _remove_dead(folder, lambda base, suffix: base + suffix == path.name or (base, suffix) in
                        ((path.stem, path.suffix), ("probe", ".tmp")))
    if inside and path.is_dir():
        said += _remove_dead(path, lambda base, suffix: True)
    return said


def _remove_dead(folder: Path, wanted) -> list[str]:
    said = []
    try:
        entries = list(folder.iterdir())
    except OSError:
        return said
    for entry in entries:
        m = _TEMP.fullmatch(entry.name)
        if m is None or not wanted(m["base"], m["suffix"]):
            continue
        pid = int(m["pid"])
        if pid == os.getpid() or _running(pid):
            continue
        try:
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
        except OSError:
            continue
        said.append(f"removed {entry}, a temporary left by process {pid}, which is no longer running")
    return said


def finite_or_none(obj):
    """JSON has no NaN/inf: replace them (in nested dicts/lists) by null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    return obj
