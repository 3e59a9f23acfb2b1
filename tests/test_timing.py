"""The benchmarks' timing helper (taichi_soft/timing.py) with fake clocks and callables:
warm-up not timed, setup not timed, sync around each clock reading, round-robin order, medians."""
import pytest

from taichi_soft.timing import Candidate, time_candidates, time_one


class FakeClock:
    """A clock that each timed call advances by a chosen amount; records every event."""

    def __init__(self):
        self.now = 0.0
        self.events = []

    def __call__(self):
        self.events.append("clock")
        return self.now

    def work(self, name, seconds):
        def run():
            self.events.append(f"run {name}")
            self.now += seconds
            return name
        return run

    def note(self, what):
        def f(*_):
            self.events.append(what)
            self.now += 100.0  # untimed work: must not show in any sample
        return f


def test_warmup_and_setup_are_not_timed_and_sync_brackets_each_reading():
    clock = FakeClock()
    t = time_one(clock.work("a", 2.0), 3, setup=clock.note("setup"), warmup=clock.note("warmup"),
                 sync=lambda: clock.events.append("sync"), clock=clock, cpu_clock=lambda: 0.0)
    assert t.wall == [2.0, 2.0, 2.0] and t.repeats == 3 and t.last == "a"
    assert clock.events[:2] == ["warmup", "sync"]
    assert clock.events[2:8] == ["setup", "sync", "clock", "run a", "sync", "clock"]
    assert clock.events.count("warmup") == 1 and clock.events.count("run a") == 3


def test_candidates_are_interleaved_round_robin_with_the_order_rotated():
    clock = FakeClock()
    cands = {n: Candidate(clock.work(n, 1.0), sync=lambda: None) for n in "abc"}
    time_candidates(cands, 3, clock=clock, cpu_clock=lambda: 0.0)
    runs = [e[4:] for e in clock.events if e.startswith("run")]
    assert runs == list("abc" "bca" "cab")
    clock = FakeClock()
    cands = {n: Candidate(clock.work(n, 1.0), sync=lambda: None) for n in "ab"}
    time_candidates(cands, 2, rotate=False, clock=clock, cpu_clock=lambda: 0.0)
    assert [e[4:] for e in clock.events if e.startswith("run")] == list("abab")


def test_median_min_and_cpu_median_of_the_samples():
    durations = iter([5.0, 1.0, 3.0, 2.0])
    clock = FakeClock()
    cpu = FakeClock()

    def run():
        d = next(durations)
        clock.now += d
        cpu.now += d / 2

    t = time_one(run, 4, sync=lambda: None, clock=clock, cpu_clock=cpu)
    assert t.wall == [5.0, 1.0, 3.0, 2.0]
    assert t.median == pytest.approx(2.5) and t.min == 1.0 and t.cpu_median == pytest.approx(1.25)


def test_done_stops_only_that_candidate():
    clock = FakeClock()
    cands = {"stops": Candidate(clock.work("stops", 1.0), sync=lambda: None, done=lambda r: True),
             "goes": Candidate(clock.work("goes", 1.0), sync=lambda: None)}
    out = time_candidates(cands, 4, clock=clock, cpu_clock=lambda: 0.0)
    assert out["stops"].repeats == 1 and out["goes"].repeats == 4
