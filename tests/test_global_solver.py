"""fast_mass_spring's global_solver = by_stiffness: the prefactored matrix on soft springs, Jacobi
PCG on stiff ones (fast_mass_spring_laplacian.py). A module of its own: each integrator built adds
Taichi field trees, and test_implicit.py's runtime holds as many as Taichi 1.7 allows.
"""
import numpy as np
import pytest

from physics_helpers import moving_cube, run_integrator
from taichi_soft.sim.integrators import make_integrator

FRAME = 1.0 / 60.0


@pytest.mark.parametrize("mode", ["serial", "parallel"])
def test_by_stiffness_is_the_factor_on_soft_springs_and_jacobi_pcg_on_stiff(mode):
    """global_solver = by_stiffness: at h^2 k_max / m_min <= 10 the step is
    cholesky's, above it pcg's, bit for bit, switched at run time when dt changes (2000 N/m, 1 kg:
    2000 h^2 is 0.56 at 1/60 s and 20 at 0.1 s)."""
    model, terrain, x0 = moving_cube(n=3)
    opts = {"mode": mode}
    # One integrator per solver, each compiled once and reset between runs; (solver, dt) -> positions
    # after 3 steps.
    integrators, refs = {}, {}

    def run(integ, dt):
        x, _, done = run_integrator(integ, model, terrain, dt, 3, x0=x0)
        assert done == 3
        return x

    def ref(solver, dt):
        if solver not in integrators:
            integrators[solver] = make_integrator("fast_mass_spring", model, terrain, {**opts, "global_solver": solver})
        if (solver, dt) not in refs:
            refs[solver, dt] = run(integrators[solver], dt)
        return refs[solver, dt]

    integ = make_integrator("fast_mass_spring", model, terrain, {**opts, "global_solver": "by_stiffness"})
    for dt, same_as in ((FRAME, "cholesky"), (0.1, "pcg"), (FRAME, "cholesky")):
        x = run(integ, dt)
        assert integ.stats()["jacobi_pcg_now"] == (same_as == "pcg")
        x_ref = ref(same_as, dt)
        assert np.array_equal(x, x_ref), (dt, np.abs(x - x_ref).max())
    # the two solvers do take different steps there, so the equality above says which one ran
    assert np.abs(ref("cholesky", 0.1) - ref("pcg", 0.1)).max() > 1e-9
