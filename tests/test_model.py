"""Lattice, springs and forces: counts, rest lengths, forces against finite differences."""
import numpy as np
import pytest

from taichi_soft import lattice
from taichi_soft.lattice import BEND, SHEAR, STRETCH

from physics_helpers import accelerations, build, numeric_gradient, spring_energy


@pytest.mark.parametrize("n, expected", [(2, (12, 16, 0)), (3, (54, 104, 27)), (10, (2700, 7776, 2400))])
def test_spring_counts(n, expected):
    _, kinds = lattice.lattice_springs(n)
    assert tuple(np.bincount(kinds, minlength=3)) == expected
    # and the closed forms: 3 n^2 (n-1); 6 n (n-1)^2 + 4 (n-1)^3; 3 n^2 (n-2)
    assert expected == (3 * n * n * (n - 1), 6 * n * (n - 1) ** 2 + 4 * (n - 1) ** 3, 3 * n * n * max(n - 2, 0))


def test_no_duplicate_springs():
    pairs, _ = lattice.lattice_springs(5)
    keys = {tuple(sorted(p)) for p in pairs.tolist()}
    assert len(keys) == len(pairs)


@pytest.mark.parametrize("degrees", [0.0, 37.0])
def test_rest_lengths_match_lattice_spacing(degrees):
    n, size = 5, 2.0
    model, _ = build(n=n, size=size, rotation_axis=(1.0, 2.0, 0.5), rotation_degrees=degrees)
    h = size / (n - 1)
    kinds = model.group_np % 3
    stretch_r = model.rest_np[kinds == STRETCH]
    bend_r = model.rest_np[kinds == BEND]
    shear_r = np.sort(np.unique(np.round(model.rest_np[kinds == SHEAR], 12)))
    np.testing.assert_allclose(stretch_r, h, rtol=1e-12)
    np.testing.assert_allclose(bend_r, 2 * h, rtol=1e-12)
    np.testing.assert_allclose(shear_r, [h * np.sqrt(2), h * np.sqrt(3)], rtol=1e-12)


def test_rotation_and_velocity_of_body():
    model, _ = build(n=3, size=2.0, center=(1.0, 2.0, 3.0), rotation_axis=(0, 0, 1), rotation_degrees=90,
                     velocity=(1.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 2.0))
    x, v = model.x0_np, model.v0_np
    np.testing.assert_allclose(x.mean(axis=0), [1, 2, 3], atol=1e-12)
    # 90 degrees about z maps the lattice's +x corner direction to +y
    r = x - x.mean(axis=0)
    np.testing.assert_allclose(v, np.array([1.0, 0, 0]) + np.cross([0, 0, 2.0], r), atol=1e-12)
    np.testing.assert_allclose(lattice.rotation_matrix((0, 0, 1), 90) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_surface_triangles_face_outward():
    n = 4
    x = lattice.lattice_points(n, 1.0)
    t = lattice.surface_triangles(n)
    assert t.shape == (12 * (n - 1) ** 2, 3)
    a, b, c = x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]
    normal = np.cross(b - a, c - a)
    assert np.all(np.einsum("ij,ij->i", normal, (a + b + c) / 3) > 0)


@pytest.mark.parametrize("strategy", ["per_spring", "gather"])
def test_spring_force_is_minus_energy_gradient(strategy):
    rng = np.random.default_rng(0)
    model, terrain = build(n=3, size=1.0, stretch=(1500.0, 0.0), shear=(900.0, 0.0), bend=(300.0, 0.0))
    x = model.x0_np + 0.05 * rng.standard_normal(model.x0_np.shape)
    v = np.zeros_like(x)
    f = accelerations(model, terrain, x, v, strategy) * model.mass_np[:, None]
    grad = numeric_gradient(lambda y: spring_energy(model, y), x)
    np.testing.assert_allclose(f, -grad, rtol=1e-6, atol=1e-6 * np.abs(grad).max())


def test_damper_force_is_minus_dissipation_gradient():
    """Damper force = -dR/dv with Rayleigh dissipation R = sum 1/2 kd ((v_a - v_b) . l)^2."""
    rng = np.random.default_rng(1)
    model, terrain = build(n=3, size=1.0, stretch=(1.0, 40.0), shear=(1.0, 25.0), bend=(1.0, 10.0))
    x = model.x0_np.copy()  # at rest length: spring forces vanish, only dampers act
    v = rng.standard_normal(x.shape)
    f = accelerations(model, terrain, x, v) * model.mass_np[:, None]
    a, b = model.pairs_np[:, 0], model.pairs_np[:, 1]
    kd = model.group_kd.to_numpy()[model.group_np]
    d = x[a] - x[b]
    l = d / np.linalg.norm(d, axis=1, keepdims=True)

    def dissipation(vel):
        return 0.5 * np.sum(kd * np.einsum("ij,ij->i", vel[a] - vel[b], l) ** 2)

    grad = numeric_gradient(dissipation, v)
    np.testing.assert_allclose(f, -grad, rtol=1e-6, atol=1e-8)


def test_zero_length_spring_gives_finite_force():
    model, terrain = build(n=2, size=1.0, stretch=(100.0, 5.0))
    x = model.x0_np.copy()
    x[1] = x[0]  # particles 0 and 1 share a stretch spring and now coincide
    a = accelerations(model, terrain, x, np.ones_like(x))
    assert np.all(np.isfinite(a))


def test_strategies_agree_with_gravity_and_contact():
    """Per-spring and gather force evaluation are the same forces, contact included."""
    rng = np.random.default_rng(2)
    model, terrain = build(n=4, size=1.0, gravity=(0.0, -9.8, 0.0), terrain="plane",
                           geometry={"point": [0.0, -0.5, 0.0], "normal": [0.0, 1.0, 0.0]}, center=(0, 0, 0))
    x = model.x0_np + 0.01 * rng.standard_normal(model.x0_np.shape)
    v = rng.standard_normal(x.shape)
    np.testing.assert_allclose(accelerations(model, terrain, x, v, "per_spring"),
                               accelerations(model, terrain, x, v, "gather"), rtol=1e-12, atol=1e-9)


def test_initial_stretch_deforms_start_not_rest():
    model, _ = build(n=3, size=2.0, initial_stretch=(1.5, 1.0, 1.0))
    plain, _ = build(n=3, size=2.0)
    np.testing.assert_allclose(model.rest_np, plain.rest_np, rtol=1e-12)
    span = np.ptp(model.x0_np, axis=0)
    np.testing.assert_allclose(span, [3.0, 2.0, 2.0], rtol=1e-12)
