"""Benchmark machinery checked against known answers (speed itself is never asserted)."""
import numpy as np
import pytest
from conftest import run_cli

from taichi_soft.bench.stability import largest_stable_dt
from taichi_soft.sim.integrators import make_integrator
from taichi_soft.sim.model import Model
from taichi_soft.sim.contact.terrain import make_terrain


def _single_spring(k, c, m=1.0):
    """Two particles of mass m joined by one spring (stiffness k, damper c) of rest length 1."""
    x0 = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    model = Model(x0=x0, v0=np.zeros_like(x0), mass=np.full(2, m), pairs=np.array([[0, 1]]),
                  rest=np.array([1.0]), group=np.array([0]), group_k=np.array([k, k, k]),
                  group_kd=np.array([c, c, c]), gravity=(0.0, 0.0, 0.0), bodies=[])
    return model, make_terrain("none", 2, {})


def _probe(model, terrain, name, steps=20000):
    """Stable iff the oscillation's energy does not grow over ``steps`` steps (the bench's energy
    criterion). The start is a tiny stretch, so the spring stays in its linear regime: a large
    amplitude makes the lattice spring nonlinear (its push is bounded by k r) and can saturate an
    instability before velocities blow up."""
    integ = make_integrator(name, model, terrain)
    state = model.state()
    start = model.x0_np.copy()
    start[1, 0] += 1e-6
    k = model.group_k.to_numpy()[0]

    def energy(x, v):
        return 0.5 * np.sum(v * v) + 0.5 * k * (np.linalg.norm(x[1] - x[0]) - 1.0) ** 2

    e0 = energy(start, np.zeros_like(start))

    def stable(dt):
        state.set(start, np.zeros_like(start))
        integ.reset()
        integ.advance(state, dt, steps)
        return not integ.diverged and energy(*state.numpy()) <= 2 * e0

    return stable


def test_bisection_finds_explicit_euler_limit_of_damped_spring():
    """Explicit Euler on m_r x'' + c x' + k x = 0 (underdamped) is stable iff dt <= c / k."""
    k, c = 1000.0, 4.0  # reduced mass 0.5: c^2 = 16 < 4 m_r k = 2000
    model, terrain = _single_spring(k, c)
    res = largest_stable_dt(_probe(model, terrain, "explicit_euler"), 1e-4, 1e-1, rel_tol=0.005)
    assert res["bounded"]
    assert res["dt"] == pytest.approx(c / k, rel=0.03)


def test_bisection_finds_rk4_limit_of_undamped_spring():
    """RK4's stability region meets the imaginary axis at 2 sqrt 2: dt_max = 2 sqrt 2 / omega."""
    k = 1000.0
    model, terrain = _single_spring(k, 0.0)
    omega = np.sqrt(k / 0.5)  # reduced mass m / 2
    res = largest_stable_dt(_probe(model, terrain, "rk4", steps=40000), 1e-4, 1e-1, rel_tol=0.005)
    assert res["dt"] == pytest.approx(2 * np.sqrt(2) / omega, rel=0.03)


def test_work_precision_orders_on_the_smooth_case():
    """bench accuracy's fitted orders: 1, 1, 2, 4 for the explicit family on the smooth case."""
    from taichi_soft.bench import accuracy

    _, _, t_end = accuracy.CASES["smooth"]
    caps = {"explicit_euler": 1e-3, "semi_implicit_euler": 1e-3, "midpoint": 2e-3, "rk4": 2.5e-3}
    sweeps = {name: accuracy.step_sizes(t_end, 10, cap, 3) for name, cap in caps.items()}
    rows, interrupted = accuracy.run_case("smooth", sweeps, repeats=1)
    assert not interrupted and not any(r["diverged"] for r in rows)
    for name, order in {"explicit_euler": 1, "semi_implicit_euler": 1, "midpoint": 2, "rk4": 4}.items():
        assert accuracy.fitted_order(rows, name) == pytest.approx(order, abs=0.25), name
    stages = {"explicit_euler": 1, "semi_implicit_euler": 1, "midpoint": 2, "rk4": 4}  # force evaluations per step
    assert all(r["force_evals"] == stages[r["integrator"]] * r["steps"] for r in rows)


@pytest.mark.parametrize("kind", ["numpy", "warp", "yardstick"])
def test_references_of_the_speed_study_take_the_engines_steps(kind):
    """The speed study compares like with like: numpy, Warp and the plain-Taichi yardstick take
    the engine's semi-implicit steps from the same state to the same final state (f64 rounding)."""
    from taichi_soft.bench import references
    from taichi_soft.bench.speed_worker import REFERENCE_SCENE
    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import Simulation

    sim = Simulation(load_scene("plane", ["body.0.n=4", *REFERENCE_SCENE]), integrator="semi_implicit_euler")
    args = (sim.model, sim.model.x0_np, sim.model.v0_np, sim.dt)
    if kind == "numpy":
        ref = references.NumpyStepper(*args)
        state = lambda: (ref.x, ref.v)  # noqa: E731
    elif kind == "warp":
        assert references.warp_available(), "warp-lang (requirements.txt) is not installed: the Warp baseline is unchecked"
        ref = references.WarpStepper(*args)
        state = ref.numpy
    else:
        ref = references.YardstickStepper(*args)
        state = ref.numpy
    sim.advance(50)
    ref.step(50)
    x, v = state()
    assert np.abs(x - sim.state.x.to_numpy()).max() < 1e-12
    assert np.abs(v - sim.state.v.to_numpy()).max() < 1e-9
    assert np.abs(x - sim.model.x0_np).max() > 1e-4  # it moved


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    """One ``bench report --quick`` run (the heaviest command in the suite) for every test that reads
    its files: (CompletedProcess, output folder). It runs the precision study too, so its test
    reads the report's precision files and REPORT.md's precision section."""
    out = tmp_path_factory.mktemp("report") / "bench"
    return run_cli("bench", "report", "--quick", "--out", out, timeout=900), out


def test_bench_report_quick_writes_every_file(quick_report):
    r, out = quick_report
    assert r.returncode == 0, r.stderr[-2000:]
    expected = ["REPORT.md", "accuracy_smooth.csv", "accuracy_smooth_wall.png", "accuracy_smooth_evals.png",
                "accuracy_drop.csv", "accuracy_drop_wall.png", "accuracy_drop_evals.png", "stability_terrain.csv",
                "stability_stiffness.csv", "stability_stiffness.png", "speed.csv", "speed_equal.csv", "speed.json",
                "speed_cpu_f64.png", "speed_cpu_f32.png", "precision.csv", "precision_references.csv",
                "precision_wall.png", "precision_evals.png"]
    for name in expected:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    report = (out / "REPORT.md").read_text()
    for heading in ("## Work-precision", "## Work-precision at equal error", "## Stability", "## Kernel speed", "Machine:", "Command:"):
        assert heading in report
    import csv

    speed_rows = list(csv.DictReader(open(out / "speed.csv")))
    assert {r["integrator"] for r in speed_rows} >= {"explicit_euler", "semi_implicit_euler", "midpoint", "rk4"}
    # every timed run stayed finite (no diverged run's steps/s in the table), and its rate is the
    # steps it took over their median time
    assert all(r["diverged"] == "False" for r in speed_rows)
    assert all(float(r["steps_per_s"]) == pytest.approx(int(r["chunk"]) / float(r["median_s"]), rel=1e-9)
               for r in speed_rows)
    # equal settings: fast math off and on take the same steps to the same state (f64 rounding)
    assert "### Equal settings, interleaved" in report
    equal = {(r["kind"], r["fast_math"]): r for r in csv.DictReader(open(out / "speed_equal.csv"))}
    for key in (("engine", "False"), ("engine", "True")):
        assert not equal[key].get("error") and float(equal[key]["max_abs_diff"]) < 1e-12
    assert "fitted orders (smooth)" in r.stdout


def test_implicit_wins_from_the_first_stiffness_it_keeps_winning():
    """The stability report's verdict: implicit wins from the smallest stiffness at which it is at
    least WIN_MARGIN faster and stays so at every larger one."""
    from taichi_soft.bench.report_markdown import WIN_MARGIN, implicit_wins_markdown

    def rows(explicit_walls):
        out = []
        for scale, wall in explicit_walls.items():
            out.append({"integrator": "semi_implicit_euler", "stiffness_scale": scale, "dt": 1e-3, "wall_s_per_sim_s": wall})
            out.append({"integrator": "fast_mass_spring", "stiffness_scale": scale, "dt": 0.1, "wall_s_per_sim_s": 1.0})
        return out

    lines = implicit_wins_markdown(rows({1.0: 1.5, 10.0: 0.9, 100.0: 2.0, 1000.0: 9.0}), [1.0, 10.0, 100.0, 1000.0])
    assert lines[-1].endswith("from stiffness x100 on.")  # x1 won, x10 did not: the win starts at x100
    lines = implicit_wins_markdown(rows({1.0: WIN_MARGIN * 0.99, 10.0: 0.5}), [1.0, 10.0])
    assert lines[-1] == "Implicit does not win at the largest stiffness measured."


def test_precision_fronts_and_equal_error_interpolation_on_synthetic_fronts():
    """bench precision's verdict: Pareto fronts drop dominated runs, the cost at an error is
    interpolated log-log between the two front points around it (exact on a power law), the
    cheapest point's cost if it is already accurate enough, and None ("not reached") below the
    front's best error; the ratio is explicit / implicit and implicit wins from the smallest
    stiffness from which it keeps winning."""
    import math

    from taichi_soft.bench.verdict import WIN_MARGIN, cost_at_error, pareto_front, verdict, wins_from

    # error = 0.1 / cost^2 on the front; (3, 0.5) and (8, 0.01) are dominated; nan / diverged dropped
    pts = [(1.0, 0.1), (2.0, 0.025), (3.0, 0.5), (4.0, 0.00625), (8.0, 0.01), (5.0, math.nan)]
    front = pareto_front(pts)
    assert front == [(1.0, 0.1), (2.0, 0.025), (4.0, 0.00625)]
    for err in (0.05, 0.01, 0.00625):
        assert cost_at_error(front, err) == pytest.approx(math.sqrt(0.1 / err), rel=1e-12)
    assert cost_at_error(front, 0.5) == 1.0  # the cheapest run is already that accurate
    assert cost_at_error(front, 0.001) is None  # not reached: no extrapolation
    assert cost_at_error([], 0.1) is None

    def rows(scale, explicit_cost_factor, explicit_best=1e-4):
        """Implicit: error 0.1 / cost; explicit: the same curve, costlier by a factor, ending at explicit_best."""
        out = []
        for c in (1.0, 2.0, 4.0, 8.0):
            out.append({"case": "flat", "stiffness_scale": scale, "integrator": "fast_mass_spring", "diverged": False,
                        "wall_per_sim_s": c, "error": 0.1 / c})
            e = max(0.1 / c, explicit_best)
            out.append({"case": "flat", "stiffness_scale": scale, "integrator": "rk4", "diverged": False,
                        "wall_per_sim_s": c * explicit_cost_factor, "error": e})
        out.append({"case": "flat", "stiffness_scale": scale, "integrator": "rk4", "diverged": True,
                    "wall_per_sim_s": 0.01, "error": math.nan})  # a diverged run never counts
        return out

    v = verdict(rows(1.0, 0.5) + rows(10.0, 3.0) + rows(100.0, 3.0, explicit_best=0.05), errors=(0.05, 0.02))
    at = {(x["stiffness_scale"], x["error_m"]): x for x in v}
    assert at[1.0, 0.05]["implicit_cost"] == pytest.approx(2.0) and at[1.0, 0.05]["ratio"] == pytest.approx(0.5)
    assert at[10.0, 0.02]["explicit_cost"] == pytest.approx(15.0) and at[10.0, 0.02]["ratio"] == pytest.approx(3.0)
    assert at[100.0, 0.02]["explicit_cost"] is None and at[100.0, 0.02]["ratio"] == math.inf  # implicit only
    assert wins_from(v, "flat", 0.02) == 10.0
    # a loss at the largest stiffness: no win
    v = verdict(rows(1.0, 3.0) + rows(10.0, 1.0 / WIN_MARGIN), errors=(0.05,))
    assert wins_from(v, "flat", 0.05) is None


def test_bench_precision_quick_writes_files_and_its_verdict(quick_report):
    """The precision study at its quick size (run by ``bench report --quick``, as ``bench precision
    --quick`` runs it): the CSVs and plots, one row per (case, method, stiffness, step), explicit
    steps at or below 0.9 x their linear limit, and a Markdown verdict that is the one the verdict
    functions give on the CSV's rows (recomputed here)."""
    import csv
    import math

    from taichi_soft.bench import precision, verdict

    r, out = quick_report
    assert r.returncode == 0, r.stderr[-2000:]
    for name in ("REPORT.md", "precision.csv", "precision_references.csv", "precision_wall.png", "precision_evals.png",
                 "plausibility.csv"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    rows = list(csv.DictReader(open(out / "precision.csv")))
    for row in rows:
        for k in ("stiffness_scale", "dt", "wall_per_sim_s", "spring_passes_per_sim_s", "error"):
            row[k] = float(row[k])
        row["diverged"] = row["diverged"] == "True"
    keys = {(r["case"], r["integrator"], r["stiffness_scale"]) for r in rows}
    assert keys == {(c, m, s) for c in precision.CASES for m in precision.QUICK_METHODS for s in precision.QUICK_STIFFNESS}
    for row in rows:
        if row["integrator"] == "fast_mass_spring":
            assert any(row["dt"] == pytest.approx(d) for d in precision.QUICK_IMPLICIT_STEPS)
            assert row["failed_solve_steps"].isdigit() and row["energy_clamped_steps"].isdigit()  # counted
        else:
            assert float(row["dt_over_limit"]) <= 0.9 + 1e-9
        assert row["diverged"] or math.isfinite(row["error"]) or row["case"] == "ensemble"
    refs = list(csv.DictReader(open(out / "precision_references.csv")))
    assert {(x["case"], float(x["stiffness_scale"])) for x in refs} == {(c, s) for c in precision.CASES
                                                                         for s in precision.QUICK_STIFFNESS}
    md = (out / "REPORT.md").read_text()
    assert "## Work-precision at equal error" in md and "Command:" in md and "Machine:" in md
    wall_table = md.split("### Verdict")[1].splitlines()  # the first verdict: wall time
    for v in verdict.verdict(rows):
        cells = f"| {v['case']} | x{v['stiffness_scale']:g} |"
        line = next(ln for ln in wall_table if ln.startswith(cells))
        assert f"{verdict._cost(v['implicit_cost'])} / {verdict._cost(v['explicit_cost'])} / {verdict._ratio(v['ratio'])}" in line
    for case in precision.CASES:
        w = verdict.wins_from(verdict.verdict(rows), case, 0.2)
        assert (f"20 cm: x{w:g}" if w is not None else "20 cm: never") in md
    # Plausibility at frame steps: a soft cube (x1) never gains energy, never ends a step inside
    # the plane, and a push slides it as far as Coulomb friction allows a block, v^2 / (2 mu g).
    assert "## Plausibility at frame steps" in md
    plaus = list(csv.DictReader(open(out / "plausibility.csv")))
    assert {(r["integrator"], float(r["stiffness_scale"]), round(1 / float(r["dt"]))) for r in plaus} == \
        {(m, s, f) for m in precision.QUICK_METHODS if m == "fast_mass_spring" for s in precision.QUICK_STIFFNESS
         for f in (30, 60)}
    for r in plaus:
        assert r["diverged"] == "False" and float(r["energy_rise"]) <= 1e-9 and float(r["deepest_inside_m"]) < 1e-6, r
        if float(r["stiffness_scale"]) == 1.0:
            assert float(r["slide_m"]) == pytest.approx(float(r["slide_expected_m"]), rel=0.1), r


def test_bench_precision_bad_workers_is_refused_before_any_work(cli, tmp_path):
    r = cli("bench", "precision", "--quick", "--workers", "0", "--out", tmp_path / "x", timeout=60)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "--workers" in r.stderr
    assert not (tmp_path / "x").exists()


def test_spring_passes_count_every_evaluation_an_implicit_step_makes():
    """The work axis of the benchmarks: explicit methods their force evaluations; an implicit step
    one pass per objective or gradient evaluation and one per CG Hessian product (not 1 per step)."""
    from taichi_soft.sim.integrators import REGISTRY

    assert REGISTRY["rk4"].spring_passes_per_step({}) == 4
    newton = {"newton_iterations_per_step": 3.0, "line_search_halvings_per_step": 0.5, "cg_iterations_per_step": 40.0}
    assert REGISTRY["implicit_euler"].spring_passes_per_step(newton) == 1 + 3 + 0.5 + 40
    local_global = {"local_global_iterations_per_step": 12.0, "cg_iterations_per_step": 0.0}
    assert REGISTRY["fast_mass_spring"].spring_passes_per_step(local_global) == 1 + 12


def test_bench_contact_quick_slides_and_keeps_the_pile_apart(cli, tmp_path):
    """``bench contact --quick``: fast_mass_spring's slide at mu = 0.3 decelerates at mu g within
    10 % (flat faces, friction the load the pairs carried: docs/implicit.md), and
    2 s of the pile with contact keeps the landed bodies apart (pairs in contact, the deepest
    overlap under a tenth of the 0.36 m finest spacing); the Markdown and the CSV agree."""
    import csv

    r = cli("bench", "contact", "--quick", "--out", tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = {x["study"]: x for x in csv.DictReader(open(tmp_path / "contact.csv"))}
    slide, cost = rows["slide"], rows["cost"]
    assert slide["integrator"] == "fast_mass_spring" and slide["diverged"] == "False"
    assert 0.9 * float(slide["mu_g"]) < float(slide["deceleration"]) < 1.1 * float(slide["mu_g"])
    assert cost["diverged"] == "False" and float(cost["pairs_per_step"]) > 0
    assert float(cost["deepest_overlap_m"]) < 0.036
    md = (tmp_path / "CONTACT.md").read_text()
    assert f"| {float(slide['deceleration']):.2f} |" in md and f"**{float(cost['ratio']):.2f}x**" in md


def test_bench_energy_quick_finds_no_rise_and_writes_its_files(cli, tmp_path):
    """The energy matrix (bench/energy.py) at its quick size: implicit_euler on one body and
    fast_mass_spring on three_cubes end every step at or below the energy they began with (the
    step's guarantee), and the Markdown's verdict is the CSV's."""
    import csv

    r = cli("bench", "energy", "--quick", "--out", tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = list(csv.DictReader(open(tmp_path / "energy.csv")))
    assert {(x["solver"], x["scene"]) for x in rows} == {("implicit_euler", "plane"), ("fast_mass_spring", "three_cubes")}
    assert all(float(x["rise"]) <= 1e-9 and x["diverged"] == "False" and int(x["steps"]) == 30 for x in rows)
    assert "**2 of 2 cases clean**" in (tmp_path / "ENERGY.md").read_text() and "2 of 2 cases clean" in r.stdout
    assert cli("bench", "energy", "--quick", "--workers", "2", "--out", tmp_path / "b").returncode == 2
