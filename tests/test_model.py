"""Lattice, springs and forces: counts, rest lengths, forces against finite differences."""
import numpy as np
import pytest

from taichi_soft.sim import lattice
from taichi_soft.sim.lattice import BEND, SHEAR, SPRING_KINDS, STRETCH

from physics_helpers import accelerations, build, numeric_gradient, spring_energy


@pytest.mark.parametrize("n, expected", [(2, (12, 16, 0)), (3, (54, 104, 27)), (10, (2700, 7776, 2400))])
def test_spring_counts(n, expected):
    assert lattice.spring_counts(n) == expected
    # and the closed forms: 3 n^2 (n-1); 6 n (n-1)^2 + 4 (n-1)^3; 3 n^2 (n-2)
    assert expected == (3 * n * n * (n - 1), 6 * n * (n - 1) ** 2 + 4 * (n - 1) ** 3, 3 * n * n * max(n - 2, 0))


# -- the device builder against the lattice's definition and the previous (numpy) builder ----------
_SIZES = (2, 3, 4, 5, 6)


def _first_principles_springs(n):
    """{(a, b): kind} of an n^3 lattice from geometry alone: stretch joins axis neighbours, shear
    face and body diagonals (squared distance 2 or 3 spacings^2), bend axis points two apart."""
    c = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
    d = c[None, :, :] - c[:, None, :]
    d2 = (d * d).sum(-1)
    axis2 = (np.count_nonzero(d, axis=-1) == 1) & (d2 == 4)
    kind = np.full(d2.shape, -1)
    kind[d2 == 1] = STRETCH
    kind[(d2 == 2) | (d2 == 3)] = SHEAR
    kind[axis2] = BEND
    a, b = np.nonzero((kind >= 0) & (np.arange(n**3)[:, None] < np.arange(n**3)[None, :]))
    return {(int(i), int(j)): int(kind[i, j]) for i, j in zip(a, b)}


def _previous_builder_springs(n):
    """The numpy builder this project had before the device one (same offsets, same order).
    Like the rest of this comparison it spells out the group and adjacency encodings itself, so
    that a change to spring_codes.py's encodings shows up here."""
    offsets = {STRETCH: [(1, 0, 0), (0, 1, 0), (0, 0, 1)],
               SHEAR: [(1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1), (0, 1, 1), (0, 1, -1),
                       (1, 1, 1), (1, 1, -1), (1, -1, 1), (1, -1, -1)],
               BEND: [(2, 0, 0), (0, 2, 0), (0, 0, 2)]}
    idx = np.arange(n**3).reshape(n, n, n)
    pairs, kinds = [], []
    for kind, offs in offsets.items():
        for off in offs:
            src = tuple(slice(max(0, -o), n - max(0, o)) for o in off)
            dst = tuple(slice(max(0, o), n - max(0, -o)) for o in off)
            pairs.append(np.stack([idx[src].ravel(), idx[dst].ravel()], axis=1))
            kinds.append(np.full(pairs[-1].shape[0], kind))
    return np.concatenate(pairs), np.concatenate(kinds)


def _previous_adjacency(pairs, rest, group, n_particles):
    """CSR adjacency as the previous builder made it (a stable argsort of both ends)."""
    m = len(pairs)
    owner = np.concatenate([pairs[:, 0], pairs[:, 1]])
    order = np.argsort(owner, kind="stable")
    spring = np.concatenate([np.arange(m)] * 2)[order]
    offset = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=n_particles))])
    return {"adj_offset": offset, "adj_other": np.concatenate([pairs[:, 1], pairs[:, 0]])[order],
            "adj_rest": rest[spring], "adj_group": group[spring],
            "adj_spring": np.concatenate([np.arange(m), -np.arange(m) - 1])[order],
            "adj_split": offset[:-1] + np.bincount(pairs[:, 0], minlength=n_particles)}


def test_builder_matches_first_principles_and_previous_builder():
    """Bodies n = 2..6 in one model: springs, rest lengths, groups and adjacency, exactly."""
    from taichi_soft.sim.bodies import BodySpec
    from taichi_soft.sim.builder import ModelBuilder

    builder = ModelBuilder(gravity=(0.0, 0.0, 0.0))
    for n in _SIZES:
        builder.add_cube(BodySpec(n=n, size=0.5 * n, center=(3.0 * n, 1.0, -2.0), rotation_axis=(1.0, 2.0, 0.5),
                                  rotation_degrees=17.0 * n, initial_stretch=(1.2, 0.9, 1.0)))
    model = builder.finalize()
    assert model.adj_offset is None  # built only for the integrators that read it
    model.ensure_adjacency()
    pairs, rest, group = model.pairs_np, model.rest_np, model.group_np
    ref_pairs, ref_rest, ref_group = [], [], []
    for b, (n, info) in enumerate(zip(_SIZES, model.bodies)):
        p0 = info.particles.start
        local = {(int(i) - p0, int(j) - p0): int(k) for (i, j), k in zip(pairs[info.springs], group[info.springs] - 3 * b)}
        assert local == _first_principles_springs(n)
        bp, bk = _previous_builder_springs(n)
        ref_pairs.append(bp + p0)
        ref_group.append(bk + 3 * b)
        # rest lengths from the body's rest shape, rotated and moved as the previous builder did
        axis = np.linspace(-0.25 * n, 0.25 * n, n)
        x = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
        x = x @ lattice.rotation_matrix((1.0, 2.0, 0.5), 17.0 * n).T + info.spec.center
        ref_rest.append(np.linalg.norm(x[bp[:, 0]] - x[bp[:, 1]], axis=1))
    ref_pairs, ref_rest, ref_group = np.concatenate(ref_pairs), np.concatenate(ref_rest), np.concatenate(ref_group)
    np.testing.assert_array_equal(pairs, ref_pairs)
    np.testing.assert_array_equal(group, ref_group)
    np.testing.assert_allclose(rest, ref_rest, rtol=1e-12)
    assert model.spring_counts() == dict(zip(SPRING_KINDS, np.bincount(ref_group % 3, minlength=3).tolist()))
    for name, want in _previous_adjacency(ref_pairs, rest, ref_group, model.n_particles).items():
        np.testing.assert_array_equal(getattr(model, name).to_numpy(), want, err_msg=name)


def test_adjacency_of_any_graph():
    """The generic constructor (springs given as host arrays, any order) gets the same adjacency."""
    from taichi_soft.sim.model import Model

    rng = np.random.default_rng(3)
    n_particles = 7
    pairs = np.array([(a, b) for a in range(n_particles) for b in range(n_particles) if a != b and rng.random() < 0.4])
    rest = rng.random(len(pairs)) + 0.5
    group = rng.integers(0, 6, len(pairs))
    x0 = rng.standard_normal((n_particles, 3))
    model = Model(x0=x0, v0=np.zeros_like(x0), mass=np.ones(n_particles), pairs=pairs, rest=rest, group=group,
                  group_k=np.ones(6), group_kd=np.ones(6), gravity=(0.0, 0.0, 0.0), bodies=[])
    model.ensure_adjacency()
    for name, want in _previous_adjacency(pairs, rest, group, n_particles).items():
        np.testing.assert_array_equal(getattr(model, name).to_numpy(), want, err_msg=name)


def test_encodings_round_trip():
    from taichi_soft.sim import spring_codes as M

    for s in (0, 1, 17):
        assert M.is_end_a(M.end_a_code(s)) and not M.is_end_a(M.end_b_code(s))
        assert M.code_spring(M.end_a_code(s)) == s == M.code_spring(M.end_b_code(s)) == M.end_b_spring(M.end_b_code(s))
    for body in (0, 4):
        for kind in range(3):
            g = M.spring_group(body, kind)
            assert (M.group_body(g), M.group_kind(g)) == (body, kind)


@pytest.mark.parametrize("degrees", [0.0, 37.0])
def test_rest_lengths_match_lattice_spacing(degrees):
    n, size = 5, 2.0
    model, _ = build(n=n, size=size, rotation_axis=(1.0, 2.0, 0.5), rotation_degrees=degrees)
    h = size / (n - 1)
    from taichi_soft.sim.spring_codes import group_kind

    kinds = group_kind(model.group_np)
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
