"""The task executor (taichi_soft.tasks): retry, failure report, Ctrl-C, scheduler refusal, and
the same sweep results from 1 or 2 local processes and from a Dask LocalCluster."""
import _thread
import os
import signal
import time
from pathlib import Path

import pytest

from conftest import process_alive
from taichi_soft import tasks
from taichi_soft.tasks import LocalExecutor, Task, run_tasks

HERE = Path(__file__).resolve().parent


@pytest.fixture
def helpers_on_path(monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(HERE))


def test_results_come_back_in_task_order_and_a_failure_is_retried_once_then_reported(helpers_on_path, tmp_path):
    jobs = [Task(f"sq{k}", "task_helpers:square", {"x": k}) for k in range(4)]
    jobs += [Task("flaky", "task_helpers:flaky", {"marker": str(tmp_path / "flaky")}),
             Task("broken", "task_helpers:fail", {"message": "no such luck"})]
    ex = LocalExecutor(2)
    try:
        out = run_tasks(jobs, ex, bar=False)
    finally:
        ex.close()
    assert list(out.results) == ["sq0", "sq1", "sq2", "sq3", "flaky"]
    assert [out.results[f"sq{k}"] for k in range(4)] == [0, 1, 4, 9]
    assert out.results["flaky"] == "second attempt" and out.attempts["flaky"] == 2
    assert list(out.failed) == ["broken"] and out.attempts["broken"] == 2
    assert "no such luck" in out.failed["broken"] and "exit status 1" in out.failed["broken"]
    assert not out.ok and not out.interrupted


class _CtrlCOnceBusy(LocalExecutor):
    """A local executor whose client gets Ctrl-C while it waits for results, at the first wait
    after ``ready()`` holds: what a SIGINT does to the main thread (Python's handler raises
    KeyboardInterrupt there at its next check), at a moment chosen by events, not by a delay."""

    def __init__(self, workers, ready):
        super().__init__(workers)
        self.ready = ready
        self.interrupted_at = None

    def wait(self, futures, timeout):
        if self.interrupted_at is None and self.ready():
            self.interrupted_at = len(futures)
            _thread.interrupt_main()
        return LocalExecutor.wait(futures, timeout)


def test_ctrl_c_cancels_running_tasks_and_keeps_finished_ones(helpers_on_path, tmp_path):
    started, finished = tmp_path / "slow-started", tmp_path / "slow"
    jobs = [Task("quick", "task_helpers:square", {"x": 3}),
            Task("slow", "task_helpers:slow", {"seconds": 600, "marker": str(finished), "started": str(started)})]
    done = []
    # Ctrl-C once the quick task's result is in and the slow one is running in its process.
    ex = _CtrlCOnceBusy(2, ready=lambda: done == ["quick"] and started.exists())
    # Python's own SIGINT handler, as in a terminal: a process started in the background by a
    # non-interactive shell inherits SIGINT ignored, and interrupt_main() then does nothing.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    killed = False
    try:
        out = run_tasks(jobs, ex, bar=False, on_result=lambda key, result: done.append(key) or result)
        # The slow task's process (its pid in ``started``) must end now: it would sleep 600 s.
        pid = int(started.read_text())
        hang_guard = time.monotonic() + 60  # only so that a broken cancel fails instead of hanging
        while process_alive(pid) and time.monotonic() < hang_guard:
            time.sleep(0.05)
        killed = not process_alive(pid)
        if not killed:
            os.kill(pid, signal.SIGKILL)  # (so that closing the executor does not wait for it)
    finally:
        ex.close()
        signal.signal(signal.SIGINT, previous)
    assert ex.interrupted_at == 1  # the slow task was in flight when Ctrl-C came
    assert out.interrupted and out.results == {"quick": 9} and not out.failed
    assert killed, "Ctrl-C did not kill the running task's process"
    assert not finished.exists()


def test_unreachable_scheduler_is_refused_with_exit_2_in_a_few_seconds(capsys, tmp_path):
    from taichi_soft import cli

    code = cli.main(["bench", "stability", "--quick", "--out", str(tmp_path / "b"), "--scheduler", "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--scheduler tcp://127.0.0.1:9" in err[0], err
    # Dask's own reason says how long it tried: our connect timeout, not its 30 s default.
    assert f"after {tasks.CONNECT_TIMEOUT_S:g} s" in err[0], err
    assert not (tmp_path / "b").exists() or not any((tmp_path / "b").iterdir())


def test_workers_and_scheduler_exclude_each_other(capsys):
    from taichi_soft import cli

    assert cli.main(["gallery", "--workers", "2", "--scheduler", "tcp://127.0.0.1:9"]) == 2
    assert "exclude" in capsys.readouterr().err


def _comparable(rows):
    """Stability rows without the wall-time column (timing differs run to run; the physics must not)."""
    return [{k: v for k, v in r.items() if k != "wall_s_per_sim_s"} for r in rows]


def test_sweep_gives_the_same_rows_on_1_or_2_processes_and_on_a_dask_local_cluster():
    """A quick stability sweep (one integrator: a terrain task and a stiffness task) three ways."""
    from distributed import LocalCluster

    from taichi_soft.bench import sweeps
    from taichi_soft.tasks import DaskExecutor

    def sweep(executor):
        try:
            res = sweeps.run_stability(True, executor, names=["semi_implicit_euler"])
        finally:
            executor.close()
        assert not res["failed"] and not res["interrupted"]
        return res

    one = sweep(LocalExecutor(1))
    two = sweep(LocalExecutor(2))
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        dask = sweep(DaskExecutor(cluster.scheduler_address))
    assert len(one["terrain_rows"]) == 1 and len(one["stiffness_rows"]) == 2
    assert one["terrain_rows"][0]["dt"] is not None
    for other in (two, dask):
        assert _comparable(other["terrain_rows"]) == _comparable(one["terrain_rows"])
        assert _comparable(other["stiffness_rows"]) == _comparable(one["stiffness_rows"])


def test_dask_retries_a_failed_task_once_then_reports_it(helpers_on_path, tmp_path):
    from distributed import LocalCluster

    from taichi_soft.tasks import DaskExecutor

    jobs = [Task("sq", "task_helpers:square", {"x": 5}), Task("flaky", "task_helpers:flaky", {"marker": str(tmp_path / "f")}),
            Task("broken", "task_helpers:fail", {})]
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        ex = DaskExecutor(cluster.scheduler_address)
        try:
            out = run_tasks(jobs, ex, bar=False)
        finally:
            ex.close()
    assert out.results == {"sq": 25, "flaky": "second attempt"}
    assert list(out.failed) == ["broken"] and "deliberate failure" in out.failed["broken"]
    assert out.attempts == {"sq": 1, "flaky": 2, "broken": 2}
