"""Forward-mode derivatives of semi-implicit Euler runs (sim/gradients.py) and the fit built on them
(stepped by sim/tangent.py, as `fit` does).

The stepper's answers are the engine's (to 1e-12 m), its derivatives match central finite
differences (relative 1e-5), a wrong derivative fails that check, and a fit returns the truth
from a synthetic target started 2x off."""
import numpy as np

from taichi_soft.sim import Simulation, scene_from_dict
from taichi_soft.sim import gradients, tangent
from taichi_soft.sim.simulation import frame_steps

DT = 1e-3


def make(terrain=True, stretch=(500.0, 2.0), shear=(300.0, 1.0), center_y=0.8, restitution=0.5, threshold=1.0):
    data = {
        "sim": {"integrator": "semi_implicit_euler", "dt": DT, "gravity": [0.0, -9.8, 0.0]},
        "body": [{"n": 3, "size": 1.0, "particle_mass": 0.5, "center": [0.0, center_y, 0.0],
                  "rotation": {"axis": [1, 0, 1], "degrees": 20}, "initial_stretch": [1.15, 0.95, 1.0],
                  "stretch": {"k": stretch[0], "damping": stretch[1]}, "shear": {"k": shear[0], "damping": shear[1]},
                  "bend": {"k": 200.0, "damping": 1.0}}],
        "terrain": {"kind": "plane", "point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0]} if terrain
        else {"kind": "none"},
        "contact": {"restitution": restitution, "friction": 0.3, "bounce_threshold": threshold},
    }
    return Simulation(scene_from_dict(data))


def fd_check(problem, steps, names, rel=1e-6):
    """Largest relative difference of each derivative from a central finite difference."""
    vals = problem.values()
    out = {}
    for p in names:
        d = problem.trajectory(vals, steps, seed=p)
        h = rel * (abs(vals[p]) or 1.0)  # a velocity or spin starting at 0: steps of rel m/s, rad/s
        up, dn = dict(vals), dict(vals)
        up[p] += h
        dn[p] -= h
        fd = (problem.trajectory(up, steps) - problem.trajectory(dn, steps)) / (2 * h)
        out[p] = float(np.abs(fd - d).max() / np.abs(fd).max())
    return out


def test_stepper_equals_engine_on_a_drop():
    sim = make()
    res = sim.run(0.6, 30, record=True)
    engine = np.stack([f[1] for f in res.frames])
    assert engine[:, :, 1].min() < 0.01  # it reached the contact band
    mine = gradients.Problem(sim).trajectory(gradients.Problem(sim).values(), frame_steps(res.steps, 30, DT))
    assert np.abs(mine - engine).max() <= 1e-12


def test_derivatives_match_finite_differences_contact_free():
    sim = make(terrain=False)
    err = fd_check(gradients.Problem(sim), frame_steps(300, 30, DT),
                   ["k_stretch", "k_shear", "k_bend", "kd_stretch", "kd_shear", "gravity", "mass", "velocity_x",
                    "spin_z"])
    assert max(err.values()) <= 1e-5, err


def test_derivatives_match_finite_differences_on_a_drop():
    # Drops onto the plane and bounces (impacts at about 2 m/s, above the 1 m/s threshold); the
    # perturbations are far too small to move a particle across a threshold.
    sim = make(center_y=0.9)
    steps = frame_steps(500, 30, DT)
    problem = gradients.Problem(sim)
    low = problem.trajectory(problem.values(), steps)[:, :, 1].min()
    assert low < 0.01
    err = fd_check(problem, steps, ["k_stretch", "kd_stretch", "restitution", "friction", "gravity"])
    assert max(err.values()) <= 1e-5, err


def test_a_wrong_derivative_fails_the_check(monkeypatch):
    """Flip the sign of the stiffness term's derivative (the imaginary part it contributes)."""
    sim = make(terrain=False)
    problem = gradients.Problem(sim)
    real = problem._coefficients

    def flipped(values, seed):
        k, *rest = real(values, seed)
        return (k.real - 1j * k.imag if np.iscomplexobj(k) else k, *rest)

    monkeypatch.setattr(problem, "_coefficients", flipped)
    err = fd_check(problem, frame_steps(300, 30, DT), ["k_stretch"])
    assert err["k_stretch"] > 1e-5


def test_fit_recovers_stiffness_and_damping_from_free_vibration():
    sim = make(terrain=False)
    steps = frame_steps(1000, 30, DT)
    problem = tangent.TangentProblem(sim)  # what `fit` steps
    truth = problem.values()
    target = problem.trajectory(truth, steps)
    names = ["k_stretch", "kd_stretch"]
    start = dict(truth, k_stretch=2 * truth["k_stretch"], kd_stretch=0.5 * truth["kd_stretch"])
    out = gradients.fit(problem, target, steps, names, start=start, max_iters=40)
    for p in names:
        assert abs(out["values"][p] / truth[p] - 1) <= 0.01, (p, out["values"][p], truth[p])


def test_fit_recovers_initial_velocity_and_spin():
    sim = make(terrain=False)
    # the scene starts at rest; the truth moves and spins, the fit starts from rest
    problem = tangent.TangentProblem(sim)
    truth = dict(problem.values(), velocity_x=0.5, spin_y=1.5)
    steps = frame_steps(300, 30, DT)
    target = problem.trajectory(truth, steps)
    out = gradients.fit(problem, target, steps, ["velocity_x", "spin_y"], start=problem.values(), max_iters=20)
    assert abs(out["values"]["velocity_x"] - 0.5) <= 1e-6 and abs(out["values"]["spin_y"] - 1.5) <= 1e-6, out["values"]


def test_fit_recovers_friction_from_a_slide():
    # Thrown down the 45-degree plane (tests/test_tangent.py's scene): it lands and slides.
    from test_tangent import make as make_thrown

    sim = make_thrown(terrain="tilted_plane", center_y=1.2, velocity=(1.0, -1.0, 0.0))
    steps = frame_steps(600, 30, DT)
    problem = tangent.TangentProblem(sim)
    truth = problem.values()
    target = problem.trajectory(truth, steps)
    out = gradients.fit(problem, target, steps, ["friction"], start=dict(truth, friction=2 * truth["friction"]))
    assert abs(out["values"]["friction"] / truth["friction"] - 1) <= 0.05, out["values"]


def test_fit_recovers_restitution_from_a_drop():
    sim = make(center_y=0.9, restitution=0.6)
    steps = frame_steps(400, 30, DT)  # the drop and the first bounce (docs/gradients.md: later, slower impacts make the loss piecewise)
    problem = tangent.TangentProblem(sim)  # what `fit` steps
    truth = problem.values()
    target = problem.trajectory(truth, steps)
    out = gradients.fit(problem, target, steps, ["restitution"], start=dict(truth, restitution=0.3), max_iters=40)
    assert abs(out["values"]["restitution"] / truth["restitution"] - 1) <= 0.05, out["values"]


FREE = ["--scene", "free_float", "--set", "sim.integrator=semi_implicit_euler", "--set", "body.0.n=3", "--duration", "0.6"]


def test_fit_command_recovers_stiffness_and_damping(cli, tmp_path):
    target = tmp_path / "t.npz"
    assert cli("run", *FREE, "--states", str(target)).returncode == 0
    result = tmp_path / "r.json"
    p = cli("fit", *FREE, "--set", "body.0.stretch.k=4000", "--set", "body.0.stretch.damping=30", "--target",
            str(target), "--params", "k_stretch,kd_stretch", "--result", str(result), "--plot", str(tmp_path / "p.png"))
    assert p.returncode == 0, p.stderr
    assert "iteration" in p.stderr
    import json

    out = json.loads(result.read_text())
    assert abs(out["values"]["k_stretch"] / 2000.0 - 1) <= 0.01 and abs(out["values"]["kd_stretch"] / 60.0 - 1) <= 0.01
    assert out["loss_history"][-1] < out["loss_history"][0] and out["gradient_evaluations"] >= 1
    assert (tmp_path / "p.png").stat().st_size > 0


def test_fit_command_refuses_bad_input(cli, tmp_path):
    target = tmp_path / "t.npz"
    assert cli("run", *FREE, "--states", str(target)).returncode == 0
    four = [a if a != "body.0.n=3" else "body.0.n=4" for a in FREE]
    cases = [(FREE, ["--params", "k_stiff"], "unknown parameter"),
             (FREE, ["--params", "k_stretch", "--window", "5:6"], "no frame"),
             (four, ["--params", "k_stretch"], "particles")]
    for scene, extra, words in cases:
        p = cli("fit", *scene, "--target", str(target), *extra)
        assert p.returncode == 2, (extra, p.stderr)
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and words in lines[0], (extra, p.stderr)


def test_fit_recovers_stiffness_and_damping_from_eight_marker_tracks():
    sim = make(terrain=False)
    steps = frame_steps(1000, 30, DT)
    problem = tangent.TangentProblem(sim)
    truth = problem.values()
    full = problem.trajectory(truth, steps)
    corners = sorted(np.argsort(np.linalg.norm(full[0] - full[0].mean(axis=0), axis=1))[-8:].tolist())
    names = ["k_stretch", "kd_stretch"]
    start = dict(truth, k_stretch=2 * truth["k_stretch"], kd_stretch=0.5 * truth["kd_stretch"])
    out = gradients.fit(problem, full[:, corners], steps, names, start=start, max_iters=40, particles=corners)
    for p in names:
        assert abs(out["values"][p] / truth[p] - 1) <= 0.01, (p, out["values"][p], truth[p])


def test_marker_csv_is_read_in_any_row_order(tmp_path):
    from taichi_soft.commands.fit import read_markers

    path = tmp_path / "m.csv"
    path.write_text("time,particle,x,y,z\n0.1,7,1,2,3\n0,7,4,5,6\n\n0,2,7,8,9\n0.1,2,0,1,2\n")
    t, particles, target = read_markers(str(path))
    assert t.tolist() == [0.0, 0.1] and particles == [2, 7]
    assert target.tolist() == [[[7, 8, 9], [4, 5, 6]], [[0, 1, 2], [1, 2, 3]]]


def test_fit_command_fits_marker_tracks(cli, tmp_path):
    target = tmp_path / "t.npz"
    assert cli("run", *FREE, "--states", str(target)).returncode == 0
    data = np.load(target)
    corners = [0, 2, 6, 8, 18, 20, 24, 26]  # some particles, as a marker set would be
    lines = ["time,particle,x,y,z"] + [",".join([repr(float(t)), str(i)] + [repr(float(c)) for c in x[i]])
                                       for t, x in zip(data["t"], data["x"]) for i in corners]
    csv = tmp_path / "markers.csv"
    csv.write_text("\n".join(lines) + "\n")
    result = tmp_path / "r.json"
    p = cli("fit", *FREE, "--set", "body.0.stretch.k=4000", "--target", str(csv), "--params", "k_stretch",
            "--result", str(result), "--plot", str(tmp_path / "p.png"))
    assert p.returncode == 0, p.stderr
    import json

    out = json.loads(result.read_text())
    assert abs(out["values"]["k_stretch"] / 2000.0 - 1) <= 0.01 and out["markers"] == corners


def test_fit_command_refuses_bad_marker_csv(cli, tmp_path):
    cases = [("time,particle,x,y,z\n0,1,2,3\n", "columns"),
             ("0,one,0,0,0\n", "not numbers"),
             ("0,0,0,0,0\n0,1,0,0,0\n0.001,0,0,0,0\n", "same particles"),
             ("0,0,0,0,0\n0,0,1,0,0\n", "second time"),
             ("time,particle,x,y,z\n", "no marker rows"),
             ("0,99,0,0,0\n", "particle 99")]
    _each_refused(cli, tmp_path, FREE, cases)


def rest_shape(spec):
    """World positions [m] of a cube body's rest lattice, [n^3, 3]: center + R p (builder.py without
    the initial stretch), made here from the lattice and rotation, not from the code under test."""
    from taichi_soft.sim.lattice import lattice_points, rotation_matrix

    rot = rotation_matrix(spec.rotation_axis, spec.rotation_degrees)
    return lattice_points(spec.n, spec.size) @ rot.T + np.asarray(spec.center)


def test_rest_point_weights_reproduce_the_rest_shape():
    # Trilinear interpolation reproduces affine maps: the weights applied to the rest lattice give
    # back the rest point itself; a point on a particle is that particle alone.
    from taichi_soft.sim.bodies import BodySpec

    spec = BodySpec(n=4, size=1.5, center=(0.3, 2.0, -1.0), rotation_axis=(1.0, 2.0, 0.5), rotation_degrees=35.0)
    rest = rest_shape(spec)
    rng = np.random.default_rng(1)
    corners = [(i * 4 + j) * 4 + k for i in (0, 3) for j in (0, 3) for k in (0, 3)]
    inside = rng.dirichlet(np.ones(8), 20) @ rest[corners]  # points of the body's convex hull
    points = np.vstack([rest[[0, 5, 63]], inside])
    particles, weights = gradients.rest_point_markers(spec, points)
    assert np.abs((weights[:, :, None] * rest[particles]).sum(axis=1) - points).max() <= 1e-12
    assert np.abs(weights.sum(axis=1) - 1).max() <= 1e-12 and weights.min() >= 0
    for m, index in enumerate([0, 5, 63]):
        assert weights[m].max() == 1.0 and particles[m][np.argmax(weights[m])] == index
    outside = rest[63] + 0.01 * (rest[63] - rest.mean(axis=0))
    try:
        gradients.rest_point_markers(spec, outside[None])
    except ValueError as e:
        assert "outside" in str(e)
    else:
        raise AssertionError("a point outside the lattice was accepted")


def test_fit_recovers_stiffness_and_damping_from_eight_rest_points():
    # The engine's run (rotated, started stretched) sampled at 8 points inside the cells, by an
    # independent trilinear interpolation (scipy) in the body's frame.
    from scipy.interpolate import RegularGridInterpolator

    from taichi_soft.sim.lattice import rotation_matrix

    sim = make(terrain=False)
    spec = sim.model.bodies[0].spec
    res = sim.run(1.0, 30, record=True)
    steps = frame_steps(res.steps, 30, DT)
    axis = np.linspace(-spec.size / 2, spec.size / 2, spec.n)
    local = np.array([[sx * 0.37, sy * 0.21, sz * 0.44] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    local[0] = (0.1, -0.45, 0.05)  # one in a central cell, one near a face
    rot = rotation_matrix(spec.rotation_axis, spec.rotation_degrees)
    points = local @ rot.T + np.asarray(spec.center)
    target = np.stack([RegularGridInterpolator((axis, axis, axis), f[1].reshape(spec.n, spec.n, spec.n, 3))(local)
                       for f in res.frames])
    particles, weights = gradients.rest_point_markers(spec, points)
    problem = tangent.TangentProblem(sim)
    truth = problem.values()
    names = ["k_stretch", "kd_stretch"]
    start = dict(truth, k_stretch=2 * truth["k_stretch"], kd_stretch=0.5 * truth["kd_stretch"])
    out = gradients.fit(problem, target, steps, names, start=start, max_iters=40, particles=particles,
                        weights=weights)
    for p in names:
        assert abs(out["values"][p] / truth[p] - 1) <= 0.01, (p, out["values"][p], truth[p])


ROTATED = [*FREE, "--set", "body.0.rotation.degrees=30"]


def marker_csv(path, data, columns):
    """A marker CSV of a `run --states` file: ``columns`` maps a particle to its identifying columns."""
    lines = [",".join([repr(float(t)), *columns(i)] + [repr(float(c)) for c in x[i]])
             for t, x in zip(data["t"], data["x"]) for i in [0, 2, 6, 8, 18, 20, 24, 26]]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_rest_point_on_a_particle_gives_its_index_form_loss(cli, tmp_path):
    import json

    from taichi_soft.sim.bodies import BodySpec

    target = tmp_path / "t.npz"
    assert cli("run", *ROTATED, "--states", str(target)).returncode == 0
    data = np.load(target)
    # free_float's body: n = 3 (set), size 2, centre 0, turned 30 degrees about (1, 0, 1); started
    # stretched, so its t = 0 positions are not its rest points
    rest = rest_shape(BodySpec(n=3, size=2.0, center=(0.0, 0.0, 0.0), rotation_degrees=30.0))
    assert np.abs(rest - data["x"][0]).max() > 0.05
    losses = []
    for name, columns in (("index", lambda i: [str(i)]), ("rest", lambda i: [repr(float(c)) for c in rest[i]])):
        csv = marker_csv(tmp_path / f"{name}.csv", data, columns)
        result = tmp_path / f"{name}.json"
        p = cli("fit", *ROTATED, "--set", "body.0.stretch.k=4000", "--target", str(csv), "--params", "k_stretch",
                "--max-iters", "1", "--result", str(result))
        assert p.returncode == 0, p.stderr
        losses.append(json.loads(result.read_text())["loss_history"])
    assert losses[0][0] > 0 and np.allclose(losses[0], losses[1], rtol=1e-12, atol=0), losses


def test_fit_command_refuses_bad_rest_point_csv(cli, tmp_path):
    cases = [("0,1,0,0,0\n0,0,0,0,0,0,0\n", "one form per file"),
             ("0,0,0,0,1,1,1\n0,0.5,0,0,1,1,1\n0.001,0,0,0,1,1,1\n", "same rest points"),
             ("0,0,0,0,1,1,1\n0,0,0,0,2,2,2\n", "second time"),
             ("0,0,0,0,1,1,1\n0,0,0,3,1,1,1\n", "outside"),
             ("0,0,0,0,1,1,1,1\n", "not 5 or 7")]
    _each_refused(cli, tmp_path, ROTATED, cases)


def _each_refused(cli, tmp_path, scene_args, cases):
    """Each (CSV text, words) target is refused by ``fit`` with exit 2 and one line naming the fault."""
    for k, (text, words) in enumerate(cases):
        path = tmp_path / f"bad{k}.csv"
        path.write_text(text)
        p = cli("fit", *scene_args, "--target", str(path), "--params", "k_stretch")
        assert p.returncode == 2, (text, p.stderr)
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and words in lines[0], (text, p.stderr)
