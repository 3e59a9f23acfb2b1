"""The two families share one contact model.

Each implicit solver, converged (tight tolerances) at a small step, must follow the explicit
reference -- RK4 at a step far below its stable limit, checked against twice that step -- through a
drop with a bounce: the centre of mass ends within ``END_TOL`` (1 cm) of the reference and the
first bounce's apex (the centre of mass's height above the lowest point of the terrain, at the
first maximum after the first minimum) is within ``APEX_TOL`` (2 %) of it. Cases: a 3^3 cube
dropped flat and tilted (30 degrees) on the plane and dropped into the bowl, at stiffness x1 and
x1000 of the default springs. If the implicit contact (held particles, restitution as a velocity
target through the body, friction in the solve) drifted from the explicit one (per-particle
impact rule, ``Terrain.respond``), the apex or the end point would move.

"Small step" means a step that resolves the stiffest spring mode: backward Euler damps a mode of
angular frequency omega by a relative O(omega h) per step, and at an impact that damping takes
bounce energy out of the compression wave. omega_max is about 180 rad/s at x1 and 5700 rad/s at
x1000 here, so the implicit step is 1e-4 s at x1 and 1.25-2.5e-6 s at x1000 (``RUNS``).
Measured on this cube (tilted drop, x1000, implicit_euler, 0.3 s): the end point is 94 / 48 / 23 /
12 mm from the reference at 10 / 5 / 2.5 / 1.25 us -- first-order convergence to the explicit answer,
i.e. the same contact model, with backward Euler's numerical damping as the only difference.

To keep the file cheap (each integrator compiles once per case and is reused for both
stiffnesses), the cube starts ``GAP`` above the terrain with the approach speed of a 0.3 m fall
and the run ends soon after the first apex (``RUNS``).
"""
import numpy as np
import pytest

from physics_helpers import build
from taichi_soft.sim.integrators import make_integrator
from taichi_soft.sim.integrators.implicit.health import CLAMP_WARN_SHARE

# Module fixtures hold Taichi objects across tests: one runtime for the module (conftest.py).
pytestmark = pytest.mark.taichi_shared

IMPLICIT = ["implicit_euler", "fast_mass_spring"]
TIGHT = {  # converged solves: stop on the residual alone [m/s^2]
    "implicit_euler": {"newton_iters": 50, "newton_tol": 2e-2, "cg_iters": 2000, "forcing": "fixed", "cg_tol": 1e-8,
                       "velocity_tol": 0.0},
    "fast_mass_spring": {"iterations": 2000, "tol": 2e-2, "velocity_tol": 1e-4},
}
TERRAINS = {
    "plane": {"point": [0.0, -1.0, 0.0], "normal": [0.0, 1.0, 0.0]},
    "bowl": {"center": [2.0, 7.0, 1.0], "radius": 7.0},
}
LOWEST = {"plane": -1.0, "bowl": 0.0}  # height of the terrain's lowest point [m]
CASES = {  # terrain, rotation [degrees] about (1, 0, 1), horizontal position of the centre [m]
    "plane_flat": ("plane", 0.0, (0.0, 0.0)),
    "plane_tilted": ("plane", 30.0, (0.0, 0.0)),
    "bowl": ("bowl", 0.0, (3.0, 1.0)),
}
SCALES = [1.0, 1000.0]
K = 2000.0  # default stiffness of every spring kind [N/m]; damping stays at the default 60 N s/m
GAP = 0.05  # [m] lowest particle above the terrain at the start
SPEED = 2.4  # [m/s] initial downward speed, about that of a 0.3 m fall (above the 1 m/s bounce threshold)
SAMPLE = 1e-3  # [s] centre-of-mass samples (apex read to g SAMPLE^2 / 8, ~1e-6 m)
DT_REFERENCE = {1.0: 2e-5, 1000.0: 2.5e-6}  # RK4 (stable limit about 6 ms at x1, 0.5 ms at x1000)
# (run length [s], implicit step [s]) per (case, stiffness): the first apex comes before the end
# (the soft cube rebounds later, after its squash); the x1000 steps are those at which backward
# Euler's first-order error is well inside 1 cm (measured end error over 0.3 s, implicit_euler,
# tilted: 94 / 48 / 23 / 12 mm at 10 / 5 / 2.5 / 1.25 us; flat: 10 mm at 2.5 us; bowl: 6 mm at 2.5 us).
RUNS = {**{(case, 1.0): (0.6, 1e-4) for case in CASES},
        ("plane_flat", 1000.0): (0.2, 1.25e-6), ("plane_tilted", 1000.0): (0.2, 1.25e-6), ("bowl", 1000.0): (0.3, 2.5e-6)}
END_TOL, APEX_TOL = 0.01, 0.02  # [m], relative


def _start(terrain_name, rotation, xz):
    """(model, terrain, x0): the cube at rest shape, lowest particle GAP above the terrain."""
    model, terrain = build(n=3, size=1.0, gravity=(0.0, -9.8, 0.0), terrain=terrain_name,
                           geometry=TERRAINS[terrain_name], center=(xz[0], 1.0, xz[1]), rotation_degrees=rotation,
                           velocity=(0.0, -SPEED, 0.0))
    x0 = model.x0_np.copy()
    for _ in range(20):  # lower the cube until its closest particle is GAP away (normals near vertical)
        x0[:, 1] -= _clearance(terrain_name, x0) - GAP
    assert abs(_clearance(terrain_name, x0) - GAP) < 1e-6
    return model, terrain, x0


def _clearance(terrain_name, x):
    """Smallest distance [m] of any particle to the terrain (numpy, independent of the engine)."""
    if terrain_name == "plane":
        return float(x[:, 1].min() + 1.0)
    g = TERRAINS["bowl"]
    return float((g["radius"] - np.linalg.norm(x - np.asarray(g["center"]), axis=1)).min())


@pytest.fixture(scope="module")
def runner():
    """``run(case, scale, name, dt)`` -> centre-of-mass heights [m] every SAMPLE and the final centre;
    one model, terrain and integrator per (terrain, integrator), reused (each compiles once)."""
    built, integrators = {}, {}

    def run(case, scale, name, dt):
        terrain_name, rotation, xz = CASES[case]
        if case not in built:
            built[case] = _start(terrain_name, rotation, xz)
        model, terrain, x0 = built[case]
        key = (case, name)
        if key not in integrators:
            integrators[key] = make_integrator(name, model, terrain, TIGHT.get(name))
        integ = integrators[key]
        for kind in ("stretch", "shear", "bend"):
            model.set_spring_params(0, kind, k=K * scale)
        state = model.state()
        state.set(x0, model.v0_np)
        terrain.reset(state.x)
        integ.reset()
        integ.stats()
        per = int(round(SAMPLE / dt))
        assert abs(per * dt - SAMPLE) < 1e-12
        heights, com = [], None
        for _ in range(int(round(RUNS[case, scale][0] / SAMPLE))):
            assert integ.advance(state, dt, per) == per and not integ.diverged
            x = state.x.to_numpy()
            com = x.mean(axis=0)
            heights.append(com[1] - LOWEST[terrain_name])
        return np.array(heights), com, integ.stats()

    return run


def _first_apex(h):
    """Height [m] of the first maximum after the first minimum; it must lie inside the run."""
    low = int(np.argmax(np.diff(h) > 0))
    top = low + int(np.argmax(h[low:]))
    assert 0 < low < top < len(h) - 1, "no bounce apex inside the run"
    return float(h[top])


@pytest.fixture(scope="module")
def reference(runner):
    """RK4 at DT_REFERENCE, checked against RK4 at twice that step (a tenth of each tolerance)."""
    cache = {}

    def get(case, scale):
        if (case, scale) not in cache:
            h, com, _ = runner(case, scale, "rk4", DT_REFERENCE[scale])
            h2, com2, _ = runner(case, scale, "rk4", 2 * DT_REFERENCE[scale])
            apex = _first_apex(h)
            assert np.linalg.norm(com2 - com) < 0.1 * END_TOL, (case, scale, com, com2)
            assert abs(_first_apex(h2) - apex) < 0.1 * APEX_TOL * apex, (case, scale)
            cache[(case, scale)] = (apex, com)
        return cache[(case, scale)]

    return get


@pytest.mark.parametrize("scale", SCALES, ids=lambda s: f"x{s:g}")
@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("name", IMPLICIT)
def test_converged_implicit_step_follows_the_explicit_reference(runner, reference, name, case, scale):
    apex_ref, com_ref = reference(case, scale)
    h, com, stats = runner(case, scale, name, RUNS[case, scale][1])
    apex = _first_apex(h)
    assert np.linalg.norm(com - com_ref) < END_TOL, (com, com_ref)
    assert abs(apex - apex_ref) < APEX_TOL * apex_ref, (apex, apex_ref)
    # Converged: implicit_euler (Newton) reaches the tolerance on every step, with no energy clamp.
    # fast_mass_spring at the microsecond steps of x1000 stops some steps at the round-off floor
    # of its line search (the residual of a position error of a few ulps is h^-2 larger there:
    # ~0.1 m/s^2 at 1.25 us) and the end-of-step energy check then clamps a few: every such
    # step is counted, none may stop far from balance (1 m/s^2, a tenth of g), and the clamp may act
    # on fewer steps than the share at which a run warns (health.CLAMP_WARN_SHARE).
    if name == "implicit_euler" or scale == 1.0:
        assert stats["failed_solve_steps"] == 0 and stats["energy_clamped_steps"] == 0, stats
    else:
        assert stats["failed_solve_max_residual_m_s2"] < 1.0, stats
        assert stats["energy_clamped_steps"] < CLAMP_WARN_SHARE * stats["steps"], stats
