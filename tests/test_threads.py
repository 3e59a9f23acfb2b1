"""The answers do not depend on how many CPU threads run the parallel loops.

The other test modules run Taichi on one CPU thread (tests/conftest.py: two test processes share
CI's two cores); this one runs the parallel kernels that sum into shared memory (forces and
contacts scattered with atomics, the explicit body-contact pass's spatial hash, the implicit
solvers' parallel driver with its reductions) on one thread and on two, from the same start, and
asks for the same states up to round-off in the order of the atomic sums.
"""
import numpy as np
import pytest

from conftest import TEST_THREADS
from taichi_soft import runtime

RUNS = [  # (integrator, options, dt [s], steps): the upper cube lands on the lower one within the run
    ("semi_implicit_euler", {}, 1e-3, 600),
    ("fast_mass_spring", {"mode": "parallel"}, 1 / 60, 36),
    ("implicit_euler", {"mode": "parallel"}, 1 / 60, 36),
]
# Two 4^3 cubes, the upper one 0.5 m above the lower one's top and offset, thrown down and sideways.
SCENE = """[[body]]
n = 4
size = 1.0
center = [0, 0.5, 0]
[[body]]
n = 4
size = 1.0
center = [0.2, 2.0, 0.1]
velocity = [0.5, -3, 0]
[terrain]
kind = "plane"
point = [0, 0, 0]
"""
TOL = 1e-6  # [m]: sums in another order differ at 1e-15 relative; chaotic contact may grow that


def _final_states(path, threads):
    from taichi_soft.sim.integrators import names
    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import Simulation

    runtime.init("cpu", "f64", cpu_max_num_threads=threads)
    out = {}
    for name, options, dt, steps in RUNS:
        sim = Simulation(load_scene(str(path), integrator_names=names()), name, dt, options=options)
        sim.reset()
        sim.advance(steps)
        assert not sim.diverged
        stats = sim.integrator.stats() if sim.contacts is None or name != "semi_implicit_euler" else sim.contacts.stats()
        out[name] = (sim.state.x.to_numpy(), stats)
    return out


def test_one_and_two_threads_give_the_same_states(tmp_path):
    path = tmp_path / "two_cubes.toml"
    path.write_text(SCENE)
    try:
        two, one = _final_states(path, 2), _final_states(path, 1)
    finally:
        runtime.init("cpu", "f64", cpu_max_num_threads=TEST_THREADS)  # as conftest.py starts it
    for name, _, _, _ in RUNS:
        (x2, stats2), (x1, _) = two[name], one[name]
        assert np.abs(x2 - x1).max() < TOL, (name, np.abs(x2 - x1).max())
        # the bodies met: the pair code ran
        assert stats2["body_pairs_in_contact_per_step" if name != "semi_implicit_euler" else "body_contact_pairs"] > 0
