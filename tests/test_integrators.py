"""Every explicit integrator through the physics checks, against analytic answers or a tiny-step reference."""
import numpy as np
import pytest

from taichi_soft.sim.integrators import REGISTRY

from physics_helpers import build, simulate, stretched, total_energy

EXPLICIT = [name for name, cls in REGISTRY.items() if not cls.implicit]
ORDERS = {"explicit_euler": 1, "semi_implicit_euler": 1, "velocity_verlet": 2, "midpoint": 2, "rk4": 4}


def test_registry_lists_the_explicit_family():
    assert {"explicit_euler", "semi_implicit_euler", "velocity_verlet", "midpoint", "rk4"} <= set(REGISTRY)


@pytest.mark.parametrize("name", EXPLICIT)
def test_momentum_conserved_without_gravity_or_terrain(name):
    model, terrain = build(n=4, size=1.5)
    rng = np.random.default_rng(3)
    x0 = stretched(model)
    v0 = rng.standard_normal(x0.shape)
    x, v, done = simulate(model, terrain, name, 1e-3, 300, x0, v0)
    assert done == 300
    p0 = (model.mass_np[:, None] * v0).sum(axis=0)
    p1 = (model.mass_np[:, None] * v).sum(axis=0)
    np.testing.assert_allclose(p1, p0, atol=1e-9 * np.abs(v0).sum())


@pytest.mark.parametrize("name", EXPLICIT)
def test_spinning_cube_keeps_its_shape(name):
    model, terrain = build(n=4, size=1.5, angular_velocity=(0.3, 1.0, 0.2), stretch=(2000.0, 60.0))
    x, v, done = simulate(model, terrain, name, 1e-3, 1000)
    assert done == 1000
    a, b = model.pairs_np[:, 0], model.pairs_np[:, 1]
    strain = np.abs(np.linalg.norm(x[a] - x[b], axis=1) / model.rest_np - 1)
    assert strain.max() < 2e-3  # centrifugal stretch m w^2 r / k is ~1e-3 of the rest length
    # and it really turned: angle of rotation ~ |w| t = 1.06 rad
    r0 = model.x0_np - model.x0_np.mean(axis=0)
    r1 = x - x.mean(axis=0)
    cos = np.sum(r0 * r1) / np.sum(r0 * r0)
    assert cos < np.cos(0.8)


@pytest.mark.parametrize("name", EXPLICIT)
def test_free_fall(name):
    g = np.array([0.0, -9.8, 0.0])
    v0 = np.array([1.0, 2.0, -0.5])
    t_end = 0.5
    errors = []
    for dt in (1e-2, 5e-3):
        # soft springs: a rigidly falling lattice has no spring force; keep rounding noise inert
        model, terrain = build(n=2, size=1.0, gravity=g, velocity=tuple(v0), stretch=(1.0, 0.0), shear=(1.0, 0.0),
                               bend=(1.0, 0.0))
        steps = int(round(t_end / dt))
        x, v, _ = simulate(model, terrain, name, dt, steps)
        exact = model.x0_np + v0 * t_end + 0.5 * g * t_end**2
        errors.append(np.abs(x - exact).max())
        np.testing.assert_allclose(v, np.broadcast_to(v0 + g * t_end, v.shape), atol=1e-10)
    if ORDERS[name] >= 2:
        # exact for constant acceleration: only rounding
        assert max(errors) < 1e-11
    else:
        # Euler's position error is 1/2 g t dt: first order, halves with dt
        assert errors[0] == pytest.approx(0.5 * 9.8 * t_end * 1e-2, rel=1e-6)
        assert errors[0] / errors[1] == pytest.approx(2.0, rel=1e-6)


def _reference(model, terrain, x0, t_end):
    dt = 2.5e-5
    x, _, _ = simulate(model, terrain, "rk4", dt, int(round(t_end / dt)), x0)
    return x


def test_convergence_orders():
    """Free-floating cube started stretched: error slopes near 1, 1, 2, 2, 4 against a tiny-step RK4."""
    model, terrain = build(n=4, size=1.5, stretch=(2000.0, 20.0), shear=(2000.0, 20.0), bend=(2000.0, 20.0))
    x0 = stretched(model)
    t_end = 0.2
    ref = _reference(model, terrain, x0, t_end)
    dts = {"explicit_euler": (1e-3, 5e-4, 2.5e-4), "semi_implicit_euler": (1e-3, 5e-4, 2.5e-4),
           "velocity_verlet": (1e-3, 5e-4, 2.5e-4),
           "midpoint": (2e-3, 1e-3, 5e-4), "rk4": (4e-3, 2e-3, 1e-3)}
    for name in EXPLICIT:
        errs = []
        for dt in dts[name]:
            x, _, done = simulate(model, terrain, name, dt, int(round(t_end / dt)), x0)
            assert done == int(round(t_end / dt))
            errs.append(np.sqrt(np.mean(np.sum((x - ref) ** 2, axis=1))))
        slopes = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
        assert slopes == pytest.approx([ORDERS[name]] * 2, abs=0.25), (name, errs, slopes)


def test_semi_implicit_euler_energy_bounded_without_dampers():
    model, terrain = build(n=4, size=1.5, stretch=(2000.0, 0.0), shear=(2000.0, 0.0), bend=(2000.0, 0.0))
    x0 = stretched(model)
    v0 = np.zeros_like(x0)
    e0 = total_energy(model, x0, v0)
    from taichi_soft.sim.integrators import make_integrator

    integ = make_integrator("semi_implicit_euler", model, terrain)
    state = model.state()
    state.set(x0, v0)
    energies = []
    for _ in range(50):  # 5 s in 0.1 s chunks
        integ.advance(state, 1e-3, 100)
        energies.append(total_energy(model, *state.numpy()))
    assert max(abs(e - e0) for e in energies) < 0.05 * e0
    # explicit Euler on the same problem gains energy: the check above can fail
    x, v, _ = simulate(model, terrain, "explicit_euler", 1e-3, 5000, x0, v0)
    assert not np.isfinite(total_energy(model, x, v)) or total_energy(model, x, v) > 1.5 * e0


@pytest.mark.parametrize("name", EXPLICIT)
def test_serial_and_parallel_launches_agree(name):
    model, terrain = build(n=4, size=1.5, gravity=(0.0, -9.8, 0.0), terrain="plane",
                           geometry={"point": [0.0, -1.0, 0.0], "normal": [0.0, 1.0, 0.0]}, center=(0.0, 0.2, 0.0))
    xs, vs, _ = simulate(model, terrain, name, 1e-3, 400, options={"mode": "serial"})
    xp, vp, _ = simulate(model, terrain, name, 1e-3, 400, options={"mode": "parallel"})
    np.testing.assert_allclose(xs, xp, atol=1e-9)
    np.testing.assert_allclose(vs, vp, atol=1e-7)


@pytest.mark.parametrize("mode", ["serial", "parallel"])
def test_divergence_stops_at_the_step(mode):
    model, terrain = build(n=3, size=1.0, stretch=(1e5, 0.0), shear=(1e5, 0.0), bend=(1e5, 0.0))
    x0 = stretched(model, (1.2, 1.0, 1.0))
    from taichi_soft.sim.integrators import make_integrator

    integ = make_integrator("explicit_euler", model, terrain, {"mode": mode})
    state = model.state()
    state.set(x0, np.zeros_like(x0))
    done = integ.advance(state, 0.01, 500)
    assert integ.diverged and 0 < done < 500
    # the same run, one step at a time, diverges on the same step
    integ2 = make_integrator("explicit_euler", model, terrain, {"mode": mode})
    state.set(x0, np.zeros_like(x0))
    k = 0
    while integ2.step(state, 0.01):
        k += 1
    assert k + 1 == done
