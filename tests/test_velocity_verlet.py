"""Velocity Verlet: second order with one force evaluation per step (the force carried between
steps), energy bounded without drift where there are no dampers, and the contact model's impact at
the crossing time against the analytic bounce of point masses."""
import numpy as np

from taichi_soft.sim.integrators import make_integrator

from physics_helpers import build, run_integrator, simulate, stretched, total_energy

G = 9.8


def test_chunked_runs_equal_one_run_and_reset_starts_afresh():
    """The carried force makes a run in pieces the same run (bit for bit), and ``reset`` forgets it:
    a second run from the start state repeats the first."""
    model, terrain = build(n=4, size=1.5, gravity=(0.0, -G, 0.0), terrain="plane",
                           geometry={"point": [0.0, -1.0, 0.0], "normal": [0.0, 1.0, 0.0]}, center=(0.0, 0.2, 0.0))
    integ = make_integrator("velocity_verlet", model, terrain)
    x1, v1, _ = run_integrator(integ, model, terrain, 1e-3, 300)
    state = model.state()
    state.set(model.x0_np, model.v0_np)
    terrain.reset(state.x)
    integ.reset()
    for _ in range(30):
        assert integ.advance(state, 1e-3, 10) == 10
    x2, v2 = state.numpy()
    assert np.array_equal(x1, x2) and np.array_equal(v1, v2)
    x3, v3, _ = run_integrator(integ, model, terrain, 1e-3, 300)
    assert np.array_equal(x1, x3) and np.array_equal(v1, v3)


def test_energy_of_a_free_undamped_cube_is_bounded_without_drift():
    """No dampers, no gravity, no terrain: leapfrog conserves a modified energy, so the energy error
    oscillates, is bounded over 10^5 steps and does not drift; being second order, its amplitude is
    far below semi-implicit Euler's at the same step (first order: O(dt) against O(dt^2))."""
    model, terrain = build(n=3, size=1.5, stretch=(2000.0, 0.0), shear=(2000.0, 0.0), bend=(2000.0, 0.0))
    x0 = stretched(model, (1.2, 0.9, 1.0))
    v0 = np.zeros_like(x0)
    e0 = total_energy(model, x0, v0)
    dt, chunk, chunks = 1e-3, 500, 200  # 10^5 steps, 100 s
    errors = {}
    for name, n_chunks in (("velocity_verlet", chunks), ("semi_implicit_euler", 10)):
        integ = make_integrator(name, model, terrain)
        state = model.state()
        state.set(x0, v0)
        out = []
        for _ in range(n_chunks):
            assert integ.advance(state, dt, chunk) == chunk
            out.append(total_energy(model, *state.numpy()) - e0)
        errors[name] = np.array(out)
    vv = errors["velocity_verlet"]
    amplitude = np.abs(vv).max()
    assert amplitude < 0.01 * e0
    assert amplitude < 0.2 * np.abs(errors["semi_implicit_euler"]).max()
    # no drift: the last tenth's mean error is the first tenth's, within a small part of the amplitude
    tenth = len(vv) // 10
    assert abs(vv[-tenth:].mean() - vv[:tenth].mean()) < 0.2 * amplitude


def _bounce(name, dt, t_end, at_crossing, restitution=0.8):
    """Final (x, analytic x) of point masses (a lattice with no springs) dropped on the plane y = -1,
    moving sideways, after one bounce each; the seed's rule without threshold or impact friction."""
    zero = (0.0, 0.0)
    model, terrain = build(n=2, size=1.0, gravity=(0.0, -G, 0.0), terrain="plane",
                           geometry={"point": [0.0, -1.0, 0.0], "normal": [0.0, 1.0, 0.0]},
                           contact={"restitution": restitution, "friction": 0.0, "epsilon": 1e-12,
                                    "bounce_threshold": 0.0, "impact_friction": False,
                                    "impact_at_crossing": at_crossing},
                           center=(0.0, 0.8, 0.0), velocity=(0.7, 0.0, 0.0), stretch=zero, shear=zero, bend=zero)
    x, _, done = simulate(model, terrain, name, dt, int(round(t_end / dt)))
    assert done == int(round(t_end / dt))
    x0 = model.x0_np
    h0 = x0[:, 1] + 1.0
    t1 = np.sqrt(2 * h0 / G)  # impact time and speed
    u = G * t1
    tau = t_end - t1
    assert (tau > 0).all() and (tau < 2 * restitution * u / G).all()  # one bounce each, in flight at the end
    exact = x0.copy()
    exact[:, 0] += 0.7 * t_end
    exact[:, 1] = -1.0 + restitution * u * tau - 0.5 * G * tau**2
    return np.abs(x - exact).max()


def test_impact_at_the_crossing_time_gives_the_analytic_bounce_at_second_order():
    """Velocity Verlet with impacts at the crossing time is within a second-order bound of the
    analytic bounce (g dt^2 / 4: the crossing is found on the chord of the step's parabola, g dt^2 / 8
    from it); the seed's end-of-step rule (the particle answered where the step ends, below the
    plane, or in the contact band above it) is first order, and far off at every step."""
    for dt in (2e-3, 1e-3, 5e-4):
        toi = _bounce("velocity_verlet", dt, 1.0, True)
        end = _bounce("velocity_verlet", dt, 1.0, False)
        assert toi < 0.25 * G * dt**2, (dt, toi)
        assert end > 0.1 * G * dt, (dt, end)  # first order (the contact band here is 1e-12 m: not the cause)


def test_impact_at_the_crossing_time_keeps_a_stopped_particle_in_the_contact_band():
    """kr = 0: a particle entering the contact band stops its normal velocity there and slides on;
    it stays in the band (above the plane, below epsilon), with no normal velocity."""
    zero = (0.0, 0.0)
    eps = 0.01
    model, terrain = build(n=2, size=1.0, gravity=(0.0, -G, 0.0), terrain="plane",
                           geometry={"point": [0.0, -1.0, 0.0], "normal": [0.0, 1.0, 0.0]},
                           contact={"restitution": 0.0, "friction": 0.0, "epsilon": eps, "impact_at_crossing": True},
                           center=(0.0, 0.0, 0.0), velocity=(0.5, 0.0, 0.0), stretch=zero, shear=zero, bend=zero)
    for name in ("velocity_verlet", "semi_implicit_euler"):
        x, v, done = simulate(model, terrain, name, 1e-3, 1500)
        assert done == 1500
        height = x[:, 1] + 1.0
        assert (height >= 0).all() and (height <= eps + 1e-9).all(), (name, height)
        assert np.abs(v[:, 1]).max() < 1e-9, name
        np.testing.assert_allclose(x[:, 0], model.x0_np[:, 0] + 0.5 * 1.5, atol=1e-9)


def test_fitted_order_on_the_benchmarks_smooth_case():
    """The work-precision study's smooth case (the free-floating cube, against its RK4 reference):
    velocity Verlet's fitted order is 2, semi-implicit Euler's 1, and for the same work (two passes
    over the springs a step against one: semi-implicit Euler at half the step) velocity Verlet's
    error is the smaller one."""
    from taichi_soft.bench import accuracy

    dts = [1e-3, 5e-4, 2.5e-4]
    ref, dt_ref = accuracy.reference("smooth", min(dts), frames=2)
    rows = {name: accuracy.measure_integrator("smooth", name, dts, ref, dt_ref, frames=2, repeats=1)
            for name in ("velocity_verlet", "semi_implicit_euler")}
    assert accuracy.fitted_order(rows["velocity_verlet"], "velocity_verlet") >= 1.9
    assert accuracy.fitted_order(rows["semi_implicit_euler"], "semi_implicit_euler") < 1.2
    for vv, sie in zip(rows["velocity_verlet"], rows["semi_implicit_euler"][1:]):
        assert vv["force_evals"] == sie["force_evals"] and vv["error_final"] < sie["error_final"]
