"""The Taichi tangent-linear stepper (sim/tangent.py): its run is the engine's semi-implicit Euler
and its derivatives, all parameters in one pass, are the complex-step reference's
(sim/gradients.py, itself checked against central finite differences in test_gradients.py)."""
import numpy as np

from taichi_soft.sim import Simulation, gradients, scene_from_dict, tangent
from taichi_soft.sim.simulation import frame_steps

DT = 1e-3
CONTACT_FREE = [p for p in gradients.PARAMS if p not in ("restitution", "friction")]


def make(terrain="plane", center_y=0.8, velocity=(0.0, 0.0, 0.0), impact_friction=False):
    data = {
        "sim": {"integrator": "semi_implicit_euler", "dt": DT, "gravity": [0.0, -9.8, 0.0]},
        "body": [{"n": 3, "size": 1.0, "particle_mass": 0.5, "center": [0.0, center_y, 0.0], "velocity": list(velocity),
                  "rotation": {"axis": [1, 0, 1], "degrees": 20}, "initial_stretch": [1.15, 0.95, 1.0],
                  "stretch": {"k": 500.0, "damping": 2.0}, "shear": {"k": 300.0, "damping": 1.0},
                  "bend": {"k": 200.0, "damping": 1.0}}],
        "terrain": {"kind": terrain},
        "contact": {"restitution": 0.5, "friction": 0.3, "bounce_threshold": 1.0, "impact_friction": impact_friction},
    }
    if terrain == "plane":
        data["terrain"].update(point=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0])
    return Simulation(scene_from_dict(data))


def largest_relative_difference(sim, steps, names):
    """Per parameter: max |tangent - complex step| / max |complex step| over frames and particles."""
    ref, fast = gradients.Problem(sim), tangent.TangentProblem(sim)
    values = ref.values()
    x, dx = fast.jacobian(values, names, steps)
    assert np.abs(x - ref.trajectory(values, steps)).max() <= 1e-12
    out = {}
    for p in names:
        d = ref.trajectory(values, steps, seed=p)
        assert np.abs(d).max() > 0, p
        out[p] = float(np.abs(dx[p] - d).max() / np.abs(d).max())
    return out


def test_run_is_the_engines_on_a_drop():
    sim = make()
    res = sim.run(0.6, 30, record=True)
    engine = np.stack([f[1] for f in res.frames])
    assert engine[:, :, 1].min() < 0.01  # it reached the contact band
    problem = tangent.TangentProblem(sim)
    mine = problem.trajectory(problem.values(), frame_steps(res.steps, 30, DT))
    assert np.abs(mine - engine).max() <= 1e-12


def test_derivatives_are_the_complex_steps_in_free_vibration():
    err = largest_relative_difference(make(terrain="none"), frame_steps(300, 30, DT), CONTACT_FREE)
    assert max(err.values()) <= 1e-9, err


def test_derivatives_are_the_complex_steps_on_a_drop():
    # Falls onto the plane and bounces (impacts about 2 m/s, above the 1 m/s threshold).
    err = largest_relative_difference(make(center_y=0.9), frame_steps(500, 30, DT), list(gradients.PARAMS))
    assert max(err.values()) <= 1e-9, err


def test_derivatives_are_the_complex_steps_sliding_with_impact_friction():
    # Thrown at the tilted plane: sliding (Coulomb's cap and the static branch) and impact friction.
    sim = make(terrain="tilted_plane", center_y=1.5, velocity=(1.0, 0.0, 0.3), impact_friction=True)
    err = largest_relative_difference(sim, frame_steps(700, 30, DT), list(gradients.PARAMS))
    assert max(err.values()) <= 1e-9, err


def test_one_pass_gives_each_parameter_its_own_column():
    """Two parameters in one pass give the columns of two one-parameter passes."""
    sim = make(terrain="none")
    problem = tangent.TangentProblem(sim)
    values, steps = problem.values(), frame_steps(100, 30, DT)
    _, both = problem.jacobian(values, ["k_shear", "mass"], steps)
    for p in ("k_shear", "mass"):
        assert np.array_equal(both[p], problem.trajectory(values, steps, seed=p))


def test_a_wrong_derivative_fails_the_check(monkeypatch):
    """The damper's term of the spring's derivative with its sign flipped."""
    monkeypatch.setattr(tangent._Stepper, "damper_derivative_sign", -1.0)
    err = largest_relative_difference(make(terrain="none"), frame_steps(100, 30, DT), ["kd_stretch"])
    assert err["kd_stretch"] > 1e-3, err
