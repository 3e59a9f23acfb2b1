"""The simulation beside the renderer: ``--pipeline serial|overlap|auto``.

``serial``: one process steps the simulation, then renders each frame (``FrameRecorder``); the
overlay and encoding run beside it on a writer thread and in ffmpeg.

``overlap``: a render process draws frame k while the run's process steps frame k+1. A thread
cannot do this: Taichi kernels keep Python's GIL while they run (a thread beside a 3.9 s kernel
got 0.5 % of its work), so the renderer gets its own process with its own Taichi runtime
(``spawn``: a forked Taichi runtime is not safe to use). The run's process (``OverlapRecorder``)
computes each frame's overlay lines and camera (``FrameLabels``), copies the positions into a
free slot of a small ring in shared memory and sends the slot's number down a pipe; the render
process (``_render_main``) copies them onto its own position field, gives the slot back and
draws, overlays and encodes exactly as ``FrameRecorder`` does in serial mode. The simulation
never sees the renderer, so its states are the serial run's, bit for bit.

Guarantees kept: outputs are written by the render process beside their destination and moved
in only when the run finishes (``FrameJob``); an error there comes back down the pipe and is
raised in the run's process as ``OutputError`` (one line, exit 4); a render process that dies
without a word (killed, crashed) is noticed within ``POLL_SECONDS`` and reported the same way,
and the temporaries it left are removed. Ctrl-C and SIGTERM are handled by the run's process,
which tells the render process to drop everything (the render process ignores SIGINT and
SIGHUP, so a Ctrl-C to the terminal's process group cannot kill it half-way; a SIGTERM of its
own, also what multiprocessing sends a daemon child when the run's Python exits, makes it drop
its outputs and exit); a run's process that dies closes the pipe and the render process drops
everything and exits.

``auto`` (the default) is ``overlap`` when frames are drawn: ``choose_pipeline`` says why.
"""
from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import time
from pathlib import Path

from ..errors import OutputError, UserError
from .recorder import FrameLabels, FrameVisits

PIPELINES = ("auto", "serial", "overlap")
SLOTS = 3  # frames the simulation may run ahead of the render process
POLL_SECONDS = 0.2  # how often a waiting run's process checks that the render process lives
START_SECONDS = 300.0  # longest wait for the render process to start (import Taichi, compile kernels)
STOP_SECONDS = 30.0  # longest wait for the render process to drop its outputs after "abort"


class RenderProcessError(OutputError):
    """The render process failed or died: its outputs were not written (exit 4, one line)."""


def choose_pipeline(kind: str, options) -> str:
    """``"serial"`` or ``"overlap"`` for ``--pipeline kind`` and a run's ``RenderOptions``.

    ``auto`` picks overlap when frames are drawn (``--video``, ``--frames``): measured faster on
    the 2-core VM, the render process's start-up (a second Python with Taichi, ~0.8 s CPU) included
    (docs/benchmarks/RENDERING.md, "Overlap"); else serial. Without frames (meshes or caches only) there is
    nothing to draw beside the simulation, and overlap is refused as a bad combination.
    """
    if kind not in PIPELINES:
        raise UserError(f"unknown pipeline {kind!r}; choose one of: {', '.join(PIPELINES)}")
    if kind == "overlap" and not options.needs_renderer:
        raise UserError("--pipeline overlap draws frames beside the simulation: it needs --video or --frames")
    if kind == "auto":
        return "overlap" if options.needs_renderer else "serial"
    return kind


def _output_paths(options) -> list[tuple[Path, bool]]:
    """(path, is a folder) of every output the render process writes."""
    paths = [(options.video, False), (options.usd, False), (options.frames, True), (options.mesh_dir, True),
             (options.pc2_dir, True)]
    return [(Path(p), folder) for p, folder in paths if p is not None]


def _kill_writers_of(pid: int, outputs):
    """SIGKILL the processes still writing a temporary of the dead render process ``pid`` beside or
    inside ``outputs`` ((path, is a folder) pairs), and wait until they are gone. Its ffmpeg runs in
    a session of its own (outputs.VideoFile) and outlives it: at the end of its input it would
    finish the MP4 and could write the temporary again after we removed it (a killed render process
    once left one behind in a suite run)."""
    from ..outfiles import temp_owner

    folders = {(p if folder else p.parent).resolve() for p, folder in outputs}
    found = []
    for entry in Path("/proc").glob("[0-9]*"):
        try:
            args = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:  # gone meanwhile, or not ours to read
            continue
        for arg in args:
            path = Path(arg.decode(errors="replace"))
            if temp_owner(path.name) == pid and path.parent.resolve() in folders:
                found.append(int(entry.name))
                break
    for other in found:
        try:
            os.kill(other, signal.SIGKILL)
        except OSError:
            continue
    deadline = time.monotonic() + STOP_SECONDS
    while found and time.monotonic() < deadline:
        found = [p for p in found if Path(f"/proc/{p}").exists() and _state(p) != "Z"]
        time.sleep(0.01)


def _state(pid: int) -> str:
    """The state letter of process ``pid`` in /proc (Z: a zombie, dead but not yet reaped)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return "Z"


class RenderProcess:
    """The render process of one run, started before the run's own Taichi runtime so that its
    start-up (import, Taichi, renderer, kernels) overlaps the run's. ``connect(sim)`` hands it the
    shared frame ring once the simulation exists; ``OverlapRecorder`` drives it from there."""

    def __init__(self, scene, options, runtime_args: dict):
        from multiprocessing import shared_memory  # noqa: F401 - fail here, not in the child

        ctx = multiprocessing.get_context("spawn")
        self.options = options
        self.conn, child = ctx.Pipe(duplex=True)
        self.proc = ctx.Process(target=_render_main, args=(child, scene, options, runtime_args),
                                name="taichi-soft-render", daemon=True)
        self.shm = None
        self.proc.start()
        child.close()
        self.ready = False
        self.free: list[int] = []
        self.closed = False

    # -- messages ----------------------------------------------------------------------------
    def send(self, *message):
        try:
            self.conn.send(message)
        except (OSError, EOFError):  # the render process is gone: say why
            self._died()

    def receive(self, timeout: float | None = None):
        """The next message from the render process (waiting up to ``timeout`` s, None: as long as
        it lives); raises ``RenderProcessError`` when it reports a failure or dies."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                if self.conn.poll(POLL_SECONDS):
                    message = self.conn.recv()
                    break
            except (OSError, EOFError):
                self._died()
            if not self.proc.is_alive() and not self.conn.poll(0):
                self._died()
            if deadline is not None and time.monotonic() > deadline:
                raise RenderProcessError(f"the render process did not answer within {timeout:.0f} s")
        if message[0] == "error":
            raise (UserError if message[1] == "UserError" else RenderProcessError)(message[2])
        if message[0] == "free":
            self.free.append(message[1])
        elif message[0] == "ready":
            self.ready = True
        return message

    def _died(self):
        try:  # a failure it reported just before it exited comes first
            while self.conn.poll(0):
                message = self.conn.recv()
                if message[0] == "error":
                    raise (UserError if message[1] == "UserError" else RenderProcessError)(message[2])
        except (OSError, EOFError):
            pass
        self.proc.join(timeout=1.0)
        code = self.proc.exitcode
        how = (f"was killed by {signal.Signals(-code).name}" if code is not None and code < 0
               else f"exited with status {code}" if code is not None else "stopped answering")
        raise RenderProcessError(f"the render process {how} before the frames were written")

    # -- the run -----------------------------------------------------------------------------
    def connect(self, sim):
        """Make the frame ring for ``sim``'s positions and send it; wait until the render process
        has opened its renderer and outputs (no Vulkan, an unwritable output: raised here, before
        any step)."""
        import numpy as np
        from multiprocessing import shared_memory

        x = sim.state.x
        shape, dtype = (x.shape[0], 3), np.dtype(sim.model.real)
        slot_bytes = int(np.prod(shape)) * dtype.itemsize
        self.shm = shared_memory.SharedMemory(create=True, size=max(1, SLOTS * slot_bytes))
        self.slots = [np.ndarray(shape, dtype, buffer=self.shm.buf, offset=k * slot_bytes) for k in range(SLOTS)]
        self.send("ring", self.shm.name, SLOTS, shape, dtype.str)
        while not self.ready:
            self.receive(START_SECONDS)

    def put(self, x, lines, cam, t: float):
        """Hand one frame over: positions ``x`` (array [n, 3]), overlay ``lines``, camera, time [s].
        Waits only while every slot is still being read (the render process is SLOTS frames behind)."""
        while not self.free:
            self.receive()
        slot = self.free.pop(0)
        self.slots[slot][...] = x
        self.send("frame", slot, lines, cam, t)

    def sync(self):
        """Wait until every frame handed over is drawn, overlaid and in the encoder's pipe."""
        self.send("sync")
        while self.receive()[0] != "synced":
            pass

    def finish(self, diverged_at) -> list[Path]:
        """Let the render process draw the rest, hold a diverged run's last frame and move its
        outputs into place; returns the paths written."""
        self.send("finish", diverged_at)
        while True:
            message = self.receive()
            if message[0] == "done":
                self._close()
                return [Path(p) for p in message[1]]

    def abort(self):
        """Tell the render process to drop its outputs and wait for it (then kill it); removes the
        temporaries a dead one left. Never raises."""
        if self.closed:
            return
        try:
            if self.proc.is_alive():
                try:
                    self.conn.send(("abort",))
                except (OSError, EOFError):
                    pass
                self.proc.join(timeout=STOP_SECONDS)
            if self.proc.is_alive():
                self.proc.kill()
                self.proc.join(timeout=STOP_SECONDS)
        finally:
            try:
                self._close()
            except OSError:  # the shared memory already gone: nothing left to free
                pass
            from ..outfiles import remove_stale_temps

            _kill_writers_of(self.proc.pid, _output_paths(self.options))
            for path, folder in _output_paths(self.options):
                try:
                    remove_stale_temps(path, inside=folder)
                except OSError:
                    pass

    def _close(self):
        if self.closed:
            return
        self.closed = True
        self.proc.join(timeout=STOP_SECONDS)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        self.conn.close()
        if self.shm is not None:
            self.slots = []
            self.shm.close()
            self.shm.unlink()


class OverlapRecorder(FrameVisits):
    """``on_frame(sim)`` for ``Simulation.run`` with a ``RenderProcess`` drawing beside it: the
    same interface and outputs as ``FrameRecorder`` (``finish()``, ``abort()``, ``frames``)."""

    def __init__(self, sim, options, render: RenderProcess, progress=None):
        self.render, self.progress = render, progress
        try:
            self.labels = FrameLabels(sim, options)
            render.connect(sim)
        except BaseException:
            render.abort()
            raise
        self.frames = 0
        self.diverged_at: float | None = None

    def hand_over(self, sim, lines, cam):
        self.render.put(sim.state.x.to_numpy(), lines, cam, sim.time)
        self.frames += 1

    def finish(self) -> list[Path]:
        try:
            return self.render.finish(self.diverged_at)
        except BaseException:
            self.render.abort()
            raise

    def abort(self):
        self.render.abort()


# -- the render process ----------------------------------------------------------------------
class _Mirror:
    """What ``FrameRecorder`` reads of a ``Simulation``, built from the same scene: model,
    terrain, scene, integrator name, dt and a state whose positions are the ones received."""

    def __init__(self, scene):
        from ..sim.simulation import build_world

        data = scene.data
        self.scene = scene
        self.model, self.terrain = build_world(data)
        self.state = self.model.state()
        self.integrator_name = data["sim"]["integrator"]
        self.dt = float(data["sim"]["dt"])


def _attach(name: str):
    """The run's shared memory, without registering it with the resource tracker (the run's
    process owns and unlinks it; Python 3.11 would also unlink it when this process exits)."""
    from multiprocessing import resource_tracker, shared_memory

    register = resource_tracker.register
    resource_tracker.register = lambda *args, **kwargs: None
    try:
        return shared_memory.SharedMemory(name=name)
    finally:
        resource_tracker.register = register


def _render_main(conn, scene, options, runtime_args: dict):
    """Entry of the render process: open the renderer and outputs, then draw what arrives."""
    for signum in (signal.SIGINT, signal.SIGHUP):
        signal.signal(signum, signal.SIG_IGN)  # the run's process decides, and says "abort"
    signal.signal(signal.SIGTERM, _terminated)  # a SIGTERM of its own (or at exit): drop everything
    recorder = shm = None
    try:
        import numpy as np

        from .. import runtime
        from .recorder import FrameRecorder

        runtime.init(**runtime_args)
        mirror = _Mirror(scene)
        recorder = FrameRecorder(mirror, options)
        message = conn.recv()
        if message[0] != "ring":
            raise _Abort
        _, name, n_slots, shape, dtype = message
        shm = _attach(name)
        nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
        slots = [np.ndarray(shape, dtype, buffer=shm.buf, offset=k * nbytes) for k in range(n_slots)]
        conn.send(("ready",))
        for k in range(n_slots):
            conn.send(("free", k))
        while True:
            message = conn.recv()
            if message[0] == "frame":
                _, slot, lines, cam, t = message
                mirror.state.x.from_numpy(slots[slot])
                conn.send(("free", slot))
                recorder.draw(lines, cam, t)
            elif message[0] == "sync":  # every frame sent before drawn and written (benchmark.py)
                recorder.writer.flush()
                conn.send(("synced",))
            elif message[0] == "finish":
                recorder.diverged_at = message[1]
                paths = recorder.finish()
                recorder = None
                conn.send(("done", [str(p) for p in paths]))
                return
            else:
                raise _Abort
    except (_Abort, EOFError, OSError) as e:  # told to stop, or the run's process is gone
        if recorder is not None:
            recorder.abort()
        if isinstance(e, OSError) and not isinstance(e, (BrokenPipeError, ConnectionError)):
            _report(conn, e)
    except BaseException as e:  # noqa: BLE001 - reported to the run's process in one line
        if recorder is not None:
            recorder.abort()
        _report(conn, e)
    finally:
        slots = None
        if shm is not None:
            shm.close()
        conn.close()


class _Abort(Exception):
    pass


def _terminated(signum, frame):
    raise _Abort


def _report(conn, e: BaseException):
    """Send ``e`` to the run's process as one line (its own, or stderr when the pipe is gone)."""
    kind = "UserError" if isinstance(e, UserError) else "OutputError"
    text = str(e) if isinstance(e, (UserError, OutputError)) else f"the render process failed: {type(e).__name__}: {e}"
    try:
        conn.send(("error", kind, text))
    except (OSError, EOFError):
        print(f"error: {text}", file=sys.stderr)
