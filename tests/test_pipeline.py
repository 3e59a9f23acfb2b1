"""--pipeline overlap: a render process draws beside the simulation (taichi_soft/render/pipeline.py).

Every test runs the command line in a child process on a tiny scene (a 4^3 cube, 96x64 frames):
the same states as serial, and what a failure, a kill or a signal leaves behind.
"""
import hashlib
import os
import signal
import subprocess
import sys
import time
import uuid

import numpy as np
import pytest

from conftest import ROOT, process_alive

SMALL = ["--set", "body.0.n=4", "--resolution", "96x64", "--fps", "20"]


def _command(*args):
    return [sys.executable, str(ROOT / "main.py"), "run", *SMALL, *map(str, args)]


def _env(marker, **extra):
    """The test's environment plus a marker that every process of the run inherits (ffmpeg too)."""
    return dict(os.environ, PYTHONUNBUFFERED="1", TAICHI_SOFT_TEST_MARK=marker, **extra)


def _marked(marker) -> list[int]:
    """Pids of live processes that carry ``marker`` in their environment."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            with open(f"/proc/{entry}/environ", "rb") as f:
                if f"TAICHI_SOFT_TEST_MARK={marker}".encode() in f.read().split(b"\0") and process_alive(int(entry)):
                    found.append(int(entry))
        except OSError:
            continue
    return found


def _no_processes_left(marker, wait=15.0) -> list[int]:
    deadline = time.time() + wait
    while _marked(marker) and time.time() < deadline:
        time.sleep(0.2)
    return _marked(marker)


def _md5(path):
    return hashlib.md5(path.read_bytes()).hexdigest()


def _hidden(folder) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*"))


def _old_outputs(tmp_path):
    """Outputs of an 'earlier run' that a failed run must leave as they are."""
    video, frames, states = tmp_path / "v.mp4", tmp_path / "f", tmp_path / "s.npz"
    video.write_bytes(b"old video")
    frames.mkdir()
    (frames / "frame_00000.png").write_bytes(b"old frame")
    states.write_bytes(b"old states")
    return video, frames, states, (_md5(video), _md5(frames / "frame_00000.png"), _md5(states))


def _unchanged(video, frames, states, old):
    return (_md5(video), _md5(frames / "frame_00000.png"), _md5(states)) == old and \
        sorted(p.name for p in frames.iterdir()) == ["frame_00000.png"]


def test_overlap_gives_the_serial_states_and_frames(tmp_path):
    marker = uuid.uuid4().hex
    runs = {}
    for mode in ("serial", "overlap"):
        out = tmp_path / mode
        out.mkdir()
        r = subprocess.run(_command("--duration", "0.3", "--pipeline", mode, "--states", out / "s.npz",
                                    "--frames", out / "f", "--video", out / "v.mp4"),
                           env=_env(marker), capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        runs[mode] = out
    a, b = np.load(runs["serial"] / "s.npz"), np.load(runs["overlap"] / "s.npz")
    assert sorted(a.files) == sorted(b.files) == ["t", "v", "x"]
    assert len(a["t"]) == 7  # frames at 0, 0.05, ..., 0.3 s
    for key in a.files:  # bit for bit: the simulation never sees the renderer
        assert a[key].dtype == b[key].dtype and np.array_equal(a[key], b[key]), key
    from PIL import Image

    serial = sorted((runs["serial"] / "f").iterdir())
    overlap = sorted((runs["overlap"] / "f").iterdir())
    assert [p.name for p in serial] == [p.name for p in overlap] and len(serial) == 7
    # The same kernels draw the same positions and overlay. Pixels may still differ by one level:
    # vertex normals are f32 sums of face normals added by parallel threads (meshes.py), in an
    # order the threads' timing decides (the default run: 1 pixel of 151 x 921,600 differed by 1).
    differ = 0
    for p, q in zip(serial, overlap):
        a, b = (np.asarray(Image.open(f)).astype(int) for f in (p, q))
        assert a.shape == b.shape == (64, 96, 3) and np.abs(a - b).max() <= 1, p.name
        differ += int((a != b).any(axis=-1).sum())
    assert differ <= 0.001 * 7 * 64 * 96
    first, last = (np.asarray(Image.open(overlap[k])).astype(int) for k in (0, -1))
    assert ((last[..., 0] - last[..., 2]) > 40).sum() > 50  # the orange cube, seen through the overlay's panel
    assert not np.array_equal(first, last)  # each frame its own positions
    assert _hidden(tmp_path) == [] and _no_processes_left(marker) == []


def test_an_encoder_failure_in_the_render_process_is_one_line_and_keeps_old_outputs(tmp_path):
    """ffmpeg (run by the render process) takes a few frames and fails: exit 4, one line saying
    so, every earlier output untouched, no temporaries, no process left."""
    video, frames, states, old = _old_outputs(tmp_path)
    fake = tmp_path / "ffmpeg"
    fake.write_text("#!/bin/sh\nhead -c 60000 >/dev/null\necho 'fake-encoder: broken pipe to nowhere' >&2\nexit 1\n")
    fake.chmod(0o755)
    marker = uuid.uuid4().hex
    r = subprocess.run(_command("--duration", "2", "--pipeline", "overlap", "--video", video,
                                "--frames", frames, "--states", states),
                       env=_env(marker, IMAGEIO_FFMPEG_EXE=str(fake)), capture_output=True, text=True, timeout=300)
    assert r.returncode == 4, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: video {video} was not written: ffmpeg"), r.stderr
    assert "fake-encoder: broken pipe to nowhere" in lines[0] and "--states" in lines[0]
    assert _unchanged(video, frames, states, old)
    assert _hidden(tmp_path) == [] and _no_processes_left(marker) == []


def _wait_for_staged_frames(tmp_path, proc, count=3, wait=120):
    deadline = time.time() + wait
    while time.time() < deadline and proc.poll() is None:
        staged = [p for p in tmp_path.glob(".f.*") if p.is_dir()]
        if staged and len(list(staged[0].iterdir())) >= count:
            return
        time.sleep(0.1)
    raise AssertionError(f"no frames staged (exit {proc.poll()}): {proc.communicate()[1] if proc.poll() else ''}")


def test_a_killed_render_process_is_reported_and_leaves_nothing(tmp_path):
    video, frames, states, old = _old_outputs(tmp_path)
    marker = uuid.uuid4().hex
    proc = subprocess.Popen(_command("--duration", "600", "--pipeline", "overlap", "--video", video,
                                     "--frames", frames, "--states", states),
                            env=_env(marker), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for_staged_frames(tmp_path, proc)
        renderers = [p for p in _marked(marker) if p != proc.pid and b"spawn_main" in
                     open(f"/proc/{p}/cmdline", "rb").read()]
        assert len(renderers) == 1, renderers
        os.kill(renderers[0], signal.SIGKILL)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 4, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "the render process was killed by SIGKILL" in lines[0], err
    assert _no_processes_left(marker) == []
    assert _unchanged(video, frames, states, old)
    assert _hidden(tmp_path) == []


@pytest.mark.parametrize("signum,to_group", [(signal.SIGTERM, False), (signal.SIGINT, True), (signal.SIGTERM, True)])
def test_sigterm_or_ctrl_c_during_an_overlapped_run_leaves_old_outputs(tmp_path, signum, to_group):
    """SIGTERM to the run, or Ctrl-C or SIGTERM to the whole process group (the render process
    too): the usual exit status and message, old outputs kept, nothing left behind."""
    video, frames, states, old = _old_outputs(tmp_path)
    marker = uuid.uuid4().hex
    # 600 s of video, minutes of work: with 60 s (about 4 s of work) a loaded machine once let the
    # run finish between the staged frames and the signal (exit 0).
    proc = subprocess.Popen(_command("--duration", "600", "--pipeline", "overlap", "--video", video,
                                     "--frames", frames, "--states", states),
                            env=_env(marker), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        _wait_for_staged_frames(tmp_path, proc)
        if to_group:
            os.killpg(proc.pid, signum)
        else:
            proc.send_signal(signum)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signum, err
    assert signal.Signals(signum).name in err and "Traceback" not in err, err
    assert _no_processes_left(marker) == []
    assert _unchanged(video, frames, states, old)
    assert _hidden(tmp_path) == []


@pytest.mark.parametrize("args,word", [(["--pipeline", "sideways"], "--pipeline"),
                                       (["--pipeline", "overlap", "--export-mesh", "m"], "--video or --frames")])
def test_bad_pipeline_flags_exit_2_before_any_work(tmp_path, args, word):
    r = subprocess.run(_command("--duration", "30", *args), cwd=tmp_path, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and word in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert list(tmp_path.iterdir()) == []
