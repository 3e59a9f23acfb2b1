"""Independent runs ("tasks") executed in fresh processes: locally (``--workers N``) or on a Dask
cluster (``--scheduler ADDRESS``), with a progress bar, ``RETRIES`` retries, and Ctrl-C that keeps results.

A ``Task`` names a module-level function (``"package.module:function"``) and its keyword
arguments (plain picklable data). Every attempt runs as ``python -m taichi_soft.tasks SPEC OUT``
in a new process, so each run has its own Taichi runtime (Taichi initialises once per process
and its compile cache, SNode trees and thread pool are per process); the function's return value
is pickled to OUT and travels back to the client, which alone writes the user's output files.

* Local: N threads, each waiting on one child process at a time.
* Dask: the client submits ``run_attempt`` to the cluster; the worker (started with
  ``dask worker ADDRESS`` from a checkout, see docs/gallery.md) spawns the same child process
  on its own machine and returns the result (CSV rows, or a video's bytes: no shared storage
  is assumed).

A task that fails (non-zero exit, an exception, a lost worker) is submitted again, up to ``RETRIES``
times; if it still fails it is reported in ``Outcome.failed`` (never silently missing). Ctrl-C cancels the
tasks not yet finished (local child processes are killed) and returns what finished, with
``Outcome.interrupted`` set.

Nothing here imports Taichi: the client process never needs a Taichi runtime for a sweep.
"""
from __future__ import annotations

import concurrent.futures as cf
import importlib
import os
import pickle
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import types
from dataclasses import dataclass, field
from pathlib import Path

from .errors import UserError
from .paths import ROOT

CONNECT_TIMEOUT_S = 3  # how long to try to reach a --scheduler before refusing it
POLL_S = 0.2  # how often the client wakes to redraw the bar and notice Ctrl-C
ERROR_TAIL = 1500  # characters of a failed child's stderr kept in the report
RETRIES = 1  # how many times a failed task is submitted again before it is reported failed


@dataclass(frozen=True)
class Task:
    """One independent run: ``fn(**kwargs)`` in a fresh process. ``key`` labels it (unique)."""

    key: str
    fn: str  # "package.module:function"
    kwargs: dict = field(default_factory=dict)


@dataclass
class Outcome:
    """What a sweep produced: results by key (in task order), failures by key, and whether Ctrl-C
    stopped it. ``attempts`` counts submissions per key (2 means it was retried)."""

    results: dict
    failed: dict
    interrupted: bool
    attempts: dict
    wall_seconds: float

    @property
    def ok(self) -> bool:
        return not self.failed and not self.interrupted


class TaskError(RuntimeError):
    """An attempt failed; the message holds the child's exit status and the tail of its stderr."""


# -- one attempt (runs on the client for local execution, on a Dask worker otherwise) --------------
_live: set = set()  # child processes of running local attempts, killed on Ctrl-C
_live_lock = threading.Lock()


def run_attempt(task: Task) -> object:
    """Run ``task`` once in a new Python process; return its result or raise ``TaskError``."""
    with tempfile.TemporaryDirectory(prefix="taichi-soft-task-") as tmp:
        spec, out = Path(tmp) / "spec.pkl", Path(tmp) / "out.pkl"
        spec.write_bytes(pickle.dumps(task))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
        # A new session: a Ctrl-C at the terminal reaches the client only, which then cancels
        # the children itself (so it can tell a cancelled task from a failed one).
        proc = subprocess.Popen([sys.executable, "-m", "taichi_soft.tasks", str(spec), str(out)], cwd=ROOT, env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
        with _live_lock:
            _live.add(proc)
        try:
            _, err = proc.communicate()
        finally:
            with _live_lock:
                _live.discard(proc)
        if proc.returncode != 0 or not out.exists():
            text = err.decode(errors="replace").strip()
            raise TaskError(f"{task.key}: exit status {proc.returncode}: {text[-ERROR_TAIL:] or '(no output)'}")
        return pickle.loads(out.read_bytes())


def _kill_live():
    with _live_lock:
        procs = list(_live)
    for p in procs:
        if p.poll() is None:
            p.kill()


def _child_main(spec_path: str, out_path: str) -> int:
    """Inside the fresh process: call the task's function, pickle its result to ``out_path``."""
    task = pickle.loads(Path(spec_path).read_bytes())
    module, _, name = task.fn.partition(":")
    try:
        result = getattr(importlib.import_module(module), name)(**task.kwargs)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except BaseException:
        traceback.print_exc()
        return 1
    tmp = Path(out_path + ".part")
    tmp.write_bytes(pickle.dumps(result))
    os.replace(tmp, out_path)
    return 0


# -- executors ---------------------------------------------------------------------------------------
class LocalExecutor:
    """``workers`` threads, each running one task's child process at a time."""

    def __init__(self, workers: int):
        self.slots = workers
        self.pool = cf.ThreadPoolExecutor(max_workers=workers, thread_name_prefix="task")
        self.where = f"{workers} local process{'es' if workers != 1 else ''}"

    def submit(self, task: Task, attempt: int):
        return self.pool.submit(run_attempt, task)

    @staticmethod
    def wait(futures, timeout):
        done, _ = cf.wait(futures, timeout=timeout, return_when=cf.FIRST_COMPLETED)
        return done

    @staticmethod
    def result(future):
        return future.result()

    def running(self, futures) -> int:
        return sum(1 for f in futures if f.running())

    def cancel(self, futures):
        for f in futures:
            f.cancel()
        _kill_live()

    def close(self):
        self.pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor:
    """Tasks on an existing ``dask.distributed`` cluster; each worker thread runs one child process."""

    def __init__(self, address: str, connect_timeout: float = CONNECT_TIMEOUT_S):
        try:
            from distributed import Client
        except ImportError:
            raise UserError("--scheduler needs dask.distributed: pip install 'dask[distributed]'") from None
        try:
            self.client = Client(address, timeout=connect_timeout, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as e:
            reason = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise UserError(f"--scheduler {address}: cannot reach a Dask scheduler within {connect_timeout:g} s "
                            f"({reason[:160]})") from None
        self.slots = max(1, sum(self.client.nthreads().values()))
        self.where = f"Dask scheduler {address} ({len(self.client.nthreads())} workers, {self.slots} threads)"

    def submit(self, task: Task, attempt: int):
        # pure=False and a per-attempt key: a retry is a new task, never the cached failure.
        # The task travels as bytes and the entry point by value: the scheduler unpickles the
        # graph and need not have taichi_soft installed; only the workers import it.
        return self.client.submit(_DASK_ENTRY, pickle.dumps(task), pure=False,
                                  key=f"taichi-soft-{task.key}-{attempt}-{time.time_ns()}")

    @staticmethod
    def wait(futures, timeout):
        # Polls the futures' states (``distributed.wait`` wants a default client, and this one
        # is not made the process-wide default).
        deadline = time.monotonic() + timeout
        while True:
            done = {f for f in futures if f.done()}
            if done or time.monotonic() >= deadline:
                return done
            time.sleep(0.02)

    @staticmethod
    def result(future):
        return future.result()

    def running(self, futures) -> int:
        return min(len(futures), self.slots)

    def cancel(self, futures):
        if futures:
            self.client.cancel(list(futures))

    def close(self):
        self.client.close()


def _dask_entry(spec: bytes):
    """On a Dask worker: unpickle the task and run one attempt from that machine's checkout."""
    import pickle

    from taichi_soft.tasks import run_attempt  # the worker's own checkout (PYTHONPATH, docs/gallery.md)

    try:
        return run_attempt(pickle.loads(spec))
    except Exception as e:  # a plain exception: the client need not unpickle taichi_soft classes
        raise RuntimeError(str(e)) from None


# The same function marked as defined in __main__, which cloudpickle (Dask's serializer for
# callables) sends by value, with only the builtins as globals.
_DASK_ENTRY = types.FunctionType(_dask_entry.__code__, {"__builtins__": __builtins__}, "_dask_entry")
_DASK_ENTRY.__module__ = "__main__"
_DASK_ENTRY.__qualname__ = "_dask_entry"


def default_workers() -> int:
    """All cores (the ``--workers`` default)."""
    return max(1, os.cpu_count() or 1)


def make_executor(workers: int | None = None, scheduler: str | None = None):
    """``DaskExecutor`` for a scheduler address, else ``LocalExecutor``; bad values raise ``UserError``.

    Call it before any work: an unreachable scheduler is refused within ``CONNECT_TIMEOUT_S``.
    """
    if scheduler is not None and workers is not None:
        raise UserError("--workers and --scheduler exclude each other (the cluster decides how many run)")
    if scheduler is not None:
        return DaskExecutor(scheduler)
    n = default_workers() if workers is None else workers
    if n < 1:
        raise UserError(f"--workers {n}: must be at least 1")
    return LocalExecutor(n)


# -- the sweep loop ------------------------------------------------------------------------------------
def run_tasks(tasks: list[Task], executor, label: str = "tasks", retries: int = RETRIES, bar=True,
              on_result=None) -> Outcome:
    """Run every task on ``executor``; retry each failure ``retries`` times; Ctrl-C keeps what finished.

    The executor stays open (one may serve several sweeps); the caller closes it.
    ``bar``: draw a tqdm progress bar on stderr (done / running / failed, ETA; off when stderr is
    not a terminal). Results come back in task order regardless of completion order.
    ``on_result(key, result) -> kept`` (optional) is called as each task finishes, so outputs can
    be written at once; what it returns is stored in ``Outcome.results`` in place of the result.
    """
    from .progress import TaskBar

    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        raise ValueError("task keys must be unique")
    by_key = {t.key: t for t in tasks}
    results, failed, attempts = {}, {}, {k: 0 for k in keys}
    inflight = {}  # future -> key
    start = time.perf_counter()
    progress = TaskBar(len(tasks), label, enabled=None if bar else False)
    interrupted = False

    def submit(key):
        attempts[key] += 1
        inflight[executor.submit(by_key[key], attempts[key])] = key

    try:
        for k in keys:
            submit(k)
        while inflight:
            progress.show(len(results), executor.running(inflight), len(failed))
            for fut in executor.wait(list(inflight), POLL_S):
                key = inflight.pop(fut)
                try:
                    result = executor.result(fut)
                except (KeyboardInterrupt, SystemExit):
                    raise
                except BaseException as e:  # a failed attempt, a lost worker, a cancelled future
                    # (Dask's cancelled-future error derives from asyncio's, a BaseException)
                    if attempts[key] <= retries:
                        submit(key)
                    else:
                        failed[key] = _one_line(e)
                else:
                    results[key] = on_result(key, result) if on_result else result
                progress.show(len(results), executor.running(inflight), len(failed), advance=True)
    except KeyboardInterrupt:
        interrupted = True
        executor.cancel(list(inflight))
    finally:
        progress.close(len(results), len(failed), interrupted)
    ordered = {k: results[k] for k in keys if k in results}
    return Outcome(ordered, {k: failed[k] for k in keys if k in failed}, interrupted, attempts,
                   time.perf_counter() - start)


def _one_line(e: BaseException) -> str:
    text = str(e).strip() or type(e).__name__
    lines = [ln for ln in text.splitlines() if ln.strip()]
    # the last line of a traceback says what went wrong; keep the first (exit status) too
    return lines[0] if len(lines) == 1 else f"{lines[0]} ... {lines[-1]}"


def report_failures(outcome: Outcome, what: str, stream=None) -> None:
    """One line on stderr per failed task, and one if the sweep was interrupted."""
    stream = stream or sys.stderr
    for key, err in outcome.failed.items():
        print(f"{what}: task {key} FAILED after {outcome.attempts[key]} attempts: {err}", file=stream)
    if outcome.interrupted:
        print(f"{what}: interrupted: {len(outcome.results)} of {len(outcome.attempts)} tasks finished and were kept",
              file=stream)


if __name__ == "__main__":
    sys.exit(_child_main(sys.argv[1], sys.argv[2]))
