"""Nothing lost, nothing silently ignored, through the command line: outputs on a full
disk and under SIGTERM, unwritable paths refused before the run, --set as one order-free set,
requests that cannot be honoured refused."""
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from taichi_soft.errors import UserError
from taichi_soft.sim.scene import load_scene

from conftest import ROOT, missing_tool

TINY = ["--set", "body.0.n=3", "--resolution", "160x120"]


def _md5(path):
    return hashlib.md5(path.read_bytes()).hexdigest()


def _no_hidden_files(folder):
    return [p.name for p in folder.rglob(".*")]


@pytest.fixture
def small_disk(tmp_path):
    """A 400 kB tmpfs, mounted as root or through passwordless sudo (as scripts/setup.sh installs)."""
    mount = tmp_path / "small"
    mount.mkdir()
    sudo = [] if os.geteuid() == 0 else ["sudo", "-n"]
    if sudo and (shutil.which("sudo") is None or subprocess.run(sudo + ["true"], capture_output=True).returncode):
        missing_tool("full-disk test needs root or passwordless sudo to mount a tmpfs")
    subprocess.run(sudo + ["mount", "-t", "tmpfs", "-o", "size=400k", "tmpfs", str(mount)], check=True)
    if sudo:
        subprocess.run(sudo + ["chown", f"{os.getuid()}:{os.getgid()}", str(mount)], check=True)
    yield mount
    subprocess.run(sudo + ["umount", str(mount)], check=True)


def test_full_disk_keeps_old_outputs_and_exits_non_zero(cli, small_disk):
    video, states, summary = small_disk / "v.mp4", small_disk / "s.npz", small_disk / "s.json"
    r = cli("run", *TINY, "--duration", "0.5", "--video", video, "--states", states)
    assert r.returncode == 0, r.stderr
    old = _md5(video), _md5(states)
    # A 1280x720 video with springs of 5 s (~0.7 MB) does not fit in what is left of 400 kB: the
    # encoder fails part-way, the run stops there and says so.
    r = cli("run", "--set", "body.0.n=5", "--resolution", "1280x720", "--springs", "--duration", "5",
            "--video", video, "--states", states)
    assert r.returncode == 4, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr
    assert f"video {video} was not written" in lines[0] and "No space left" in lines[0]
    assert f"--states {states} was not written either" in lines[0]
    assert (_md5(video), _md5(states)) == old
    assert _no_hidden_files(small_disk) == []
    # Without a video: 5 s of states (~1.8 MB) do not fit; the summary does, and is written.
    r = cli("run", "--set", "body.0.n=5", "--duration", "5", "--states", states, "--summary", summary)
    assert r.returncode == 4, r.stderr
    assert r.stderr.startswith(f"error: states: {states} was not written: No space left on device")
    assert _md5(states) == old[1] and _no_hidden_files(small_disk) == []
    assert json.loads(summary.read_text())["steps"] == 5000
    assert f"summary: {summary}" in r.stdout and f"states: {states}" not in r.stdout


@pytest.mark.parametrize("video", [False, True])
def test_an_interrupt_a_library_swallowed_still_stops_the_run(monkeypatch, capsys, tmp_path, video):
    """Ctrl-C whose KeyboardInterrupt a library's bare ``except:`` swallowed (Taichi has several;
    an overlapped run once finished and exited 0 that way): the run stops at the next frame or
    progress report, exits 130 and keeps the old outputs."""
    from taichi_soft import cli
    from taichi_soft.commands import common
    from taichi_soft.sim.simulation import Simulation

    monkeypatch.setattr(common, "start_taichi", lambda args: None)  # conftest's runtime is running
    advance, calls = Simulation.advance, []

    def swallowing_advance(self, n):
        calls.append(n)
        if len(calls) == 3:
            try:  # the signal arrives while the main thread is inside a library's bare except
                signal.getsignal(signal.SIGINT)(signal.SIGINT, None)
            except:  # noqa: E722
                pass
        return advance(self, n)

    monkeypatch.setattr(Simulation, "advance", swallowing_advance)
    summary, clip = tmp_path / "s.json", tmp_path / "v.mp4"
    summary.write_text("old summary")
    clip.write_bytes(b"old video")
    code = cli.main(["run", "--set", "body.0.n=3", "--duration", "20", "--summary", str(summary),
                     "--pipeline", "serial", "--resolution", "64x48"] + (["--video", str(clip)] if video else []))
    assert code == 130, capsys.readouterr().err
    assert "interrupted (SIGINT)" in capsys.readouterr().err
    assert summary.read_text() == "old summary" and clip.read_bytes() == b"old video"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json", "v.mp4"]
    assert len(calls) < 10  # stopped at the next frame, not at the end of 20 s


def test_sigterm_during_a_render_leaves_the_old_outputs_and_no_junk(tmp_path):
    video, frames = tmp_path / "v.mp4", tmp_path / "f"
    args = [sys.executable, str(ROOT / "main.py"), "run", *TINY, "--video", str(video), "--frames", str(frames)]
    assert subprocess.run(args + ["--duration", "0.2"], capture_output=True).returncode == 0
    old_video, old_frames = _md5(video), sorted(p.name for p in frames.iterdir())
    proc = subprocess.Popen(args + ["--duration", "600"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def staged():  # frames of this run already in its hidden staging folder (".f.<pid>.<hex>", the pid
        # the run's or, with --pipeline overlap, its render process's)
        return sum(1 for d in tmp_path.iterdir() if d.name.startswith(".f.") and d.is_dir() for _ in d.iterdir())

    # Signal once the render is under way (frames staged), not after a guessed delay; the process
    # ending first (an error) or no frame at all also end the wait.
    hang_guard = time.monotonic() + 600  # only so that a hung run cannot hang the suite
    while staged() < 3 and proc.poll() is None and time.monotonic() < hang_guard:
        time.sleep(0.05)
    in_progress = staged()
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert in_progress >= 3, err  # the signal hit a render in progress (600 s of video: minutes from its end)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "SIGTERM" in err and "Traceback" not in err
    assert _md5(video) == old_video
    assert sorted(p.name for p in frames.iterdir()) == old_frames
    assert _no_hidden_files(tmp_path) == []


@pytest.mark.parametrize("flag,path", [("--summary", "/proc/x.json"), ("--summary", "/sys/kernel/x.json"),
                                       ("--states", "/proc/x.npz"), ("--video", "/proc/x.mp4"),
                                       ("--frames", "/proc/frames")])
def test_unwritable_outputs_are_refused_before_the_run(cli, flag, path):
    r = cli("run", "--duration", "30", flag, path)  # 30 s would take long: refused first
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and flag in lines[0] and "cannot create files" in lines[0]


@pytest.mark.parametrize("sets", [
    ["terrain.radius=5", "terrain.kind=sphere"],
    ["body.0.stretch.k=50000", "body.0.stretch={damping=5}"],
])
def test_overrides_are_one_set_in_any_order(sets):
    a = load_scene("plane", sets).data
    b = load_scene("plane", sets[::-1]).data
    assert a == b
    if "terrain.kind=sphere" in sets:
        assert a["terrain"] == {"kind": "sphere", "center": [0.0, -1.0, 0.0], "radius": 5.0}
    else:
        assert a["body"][0]["stretch"] == {"k": 50000.0, "damping": 5.0}


def test_a_key_given_twice_is_refused_and_labels_name_the_terrain():
    with pytest.raises(UserError, match="given twice"):
        load_scene("plane", ["sim.dt=0.1", "sim.dt=0.2"])
    assert load_scene("plane", ["terrain.kind=sphere"]).label == "plane, terrain sphere"
    assert load_scene("sphere").label == "sphere"


@pytest.mark.parametrize("args,words", [
    (["--dt", "0.5", "--duration", "0.2"], ["--dt 0.5", "longer than sim.duration"]),
    (["--set", "body.0.n=1"], ["--set body.0.n=1", "body.0.n = 1"]),
    (["--set", "terrain.radius=5"], ["--set terrain.radius=5", "terrain kind 'plane'"]),
    (["--scene", "EMPTY"], ["no [[body]] table"]),
])
def test_requests_that_cannot_be_honoured_are_refused(cli, tmp_path, args, words):
    empty = tmp_path / "empty.toml"
    empty.write_text("")
    r = cli("run", *[str(empty) if a == "EMPTY" else a for a in args])
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and all(w in lines[0] for w in words), lines


def test_a_duration_that_is_not_whole_steps_says_what_is_simulated(cli, tmp_path):
    summary = tmp_path / "s.json"
    r = cli("run", "--set", "body.0.n=3", "--dt", "0.3", "--duration", "1", "--summary", summary)
    assert r.returncode == 0, r.stderr
    assert "simulating 3 steps of 0.3 s = 0.9 s" in r.stderr
    assert json.loads(summary.read_text())["sim_time"] == pytest.approx(0.9)


# -- missing folders, stale temporaries, what a --scene path is -------------------------
@pytest.mark.parametrize("flag,name", [("--video", "x.mp4"), ("--summary", "x.json"), ("--frames", "frames")])
def test_a_missing_parent_folder_is_refused_not_created(cli, tmp_path, flag, name):
    target = tmp_path / "missing" / "deeper" / name
    r = cli("run", "--duration", "30", flag, target)  # 30 s would take long: refused first
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and flag in lines[0] and "does not exist" in lines[0], lines
    assert not (tmp_path / "missing").exists()


def _dead_pid():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_stale_temporaries_of_dead_runs_are_removed_and_said(cli, tmp_path):
    """A run killed by SIGKILL leaves its hidden temporaries; the next run to the same path removes
    those of processes that are gone (and says so), never those of a live process, inside the
    project's default out/ (created when missing, the one folder that is)."""
    out = tmp_path / "out"
    out.mkdir()
    dead, live = _dead_pid(), os.getpid()
    stale = [out / f".s.{dead}.0123abcd.json", out / f".probe.{dead}.00ff00ff.tmp"]
    for p in stale:
        p.write_text("partial")
    kept = [out / f".s.{live}.cafecafe.json", out / f".other.{dead}.0badf00d.json", out / "notes.txt"]
    for p in kept:
        p.write_text("keep")
    r = cli("run", *TINY, "--duration", "0.01", "--summary", "out/s.json", "--states", "out/new/st.npz",
            cwd=tmp_path)  # out/new is created: it is inside the default out/
    assert r.returncode == 0, r.stderr
    removed = [line for line in r.stderr.splitlines() if line.startswith("note: removed ")]
    assert len(removed) == 2 and all(f"process {dead}, which is no longer running" in line for line in removed), r.stderr
    assert not any(p.exists() for p in stale)
    assert all(p.exists() for p in kept)
    assert (out / "s.json").exists() and (out / "new" / "st.npz").exists()


def test_stale_staging_folders_are_removed_but_not_live_ones(tmp_path):
    from taichi_soft.outfiles import remove_stale_temps

    dead, live = _dead_pid(), os.getpid()
    frames = tmp_path / "frames"
    old, ours = tmp_path / f".frames.{dead}.deadbeef", tmp_path / f".frames.{live}.feedf00d"
    for d in (old, ours):
        d.mkdir()
        (d / "frame_00000.png").write_bytes(b"png")
    frames.mkdir()
    inside = frames / f".frame_00003.{dead}.12345678.png"
    inside.write_bytes(b"png")
    said = remove_stale_temps(frames, inside=True)
    assert not old.exists() and not inside.exists() and ours.exists()
    assert sorted(said) == sorted(f"removed {p}, a temporary left by process {dead}, which is no longer running"
                                  for p in (old, inside))


@pytest.mark.parametrize("path,what", [("/dev/null", "is a character device"), ("DIR", "is a directory"),
                                       ("DIR/none.toml", "does not exist")])
def test_a_scene_path_that_is_not_a_file_says_what_it_is(tmp_path, path, what):
    path = path.replace("DIR", str(tmp_path))
    with pytest.raises(UserError, match=f"scene file '{path}' {what}"):
        load_scene(path)
