"""``run --error-estimate`` against the true error on the default scene (scenes/plane.toml as
shipped: the n = 10 cube tilted 30 degrees, dropped from y = 9, 5 s), per explicit method and step.

    PYTHONPATH=. .venv/bin/python studies/estimate_study.py semi_implicit_euler:1e-3,velocity_verlet:5e-4
    PYTHONPATH=. .venv/bin/python studies/estimate_study.py velocity_verlet:1e-3 --set contact.impact_at_crossing=true

True error: the largest centre-of-mass distance and rigid-fit RMS over the estimate's own sample
times (every 0.25 s) of the run at dt from RK4 at ``REFERENCE_DT`` with the same scene settings,
self-checked against RK4 at twice that step (printed first). One JSON line per method and step:
the estimates (null where withheld), the true errors, the observed orders, the estimate's wall
time and the run's. Results: docs/benchmarks/VERLET.md.
"""
import json
import sys

from taichi_soft import runtime

REFERENCE_DT = 6.25e-5  # [s]
DURATION = 5.0  # [s] the scene's
EVERY = 0.25  # [s] the estimate's sample interval for a 5 s run (20 samples)


def main(argv):
    runtime.init("cpu", "f64")
    import numpy as np

    from taichi_soft.sim import error_estimate as ee
    from taichi_soft.sim.integrators import names
    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import Simulation, step_count

    sets = [argv[k + 1] for k, a in enumerate(argv) if a == "--set"]
    methods = [m.split(":") for m in argv[0].split(",")]
    times = [EVERY * k for k in range(1, round(DURATION / EVERY) + 1)]

    def make(name, dt):
        return Simulation(load_scene("plane", sets, integrator_names=names()), integrator=name, dt=dt)

    def measures(a, b, w):
        return (max(float(np.linalg.norm(w @ x - w @ y)) for x, y in zip(a, b)),
                max(ee.rigid_fit_rms(x, y) for x, y in zip(a, b)))

    refs = []
    for dt in (REFERENCE_DT, 2 * REFERENCE_DT):
        sim = make("rk4", dt)
        xs, wall = ee.sample_run(sim, dt, round(DURATION / dt), [round(t / dt) for t in times])
        refs.append(xs)
        print(f"reference rk4 dt = {dt:g} s: {wall:.1f} s wall", flush=True)
    w = sim.model.mass_np.astype(np.float64)
    w /= w.sum()
    print("reference self-check (dt vs 2 dt): com %.3g m, shape %.3g m" % measures(refs[0], refs[1], w), flush=True)
    real = ee.sample_run
    for name, text in methods:
        dt = float(text)
        if ee._sample_steps(step_count(DURATION, dt), ee.SAMPLES) != [round(t / dt) for t in times]:
            raise SystemExit(f"dt {dt:g}: the estimate's sample times are not every {EVERY} s")
        first = {}

        def spy(sim, d, total, steps):  # keeps the estimate's own run at dt
            xs, wall = real(sim, d, total, steps)
            first.setdefault(d, (xs, wall))
            return xs, wall

        ee.sample_run = spy
        try:
            sim = make(name, dt)
            est = ee.estimate(sim, DURATION, sim.integrator.order)
        finally:
            ee.sample_run = real
        run, wall = first[dt]
        com, shape = (None, None) if run is None else measures(refs[0], run, w)
        print(json.dumps({"method": name, "dt": dt, "com_estimate": est["com_error"], "com_true": com,
                          "observed_order_com": est["observed_order_com"], "shape_estimate": est["shape_error"],
                          "shape_true": shape, "observed_order_shape": est["observed_order_shape"],
                          "estimate_wall_s": est["cost_seconds"], "run_wall_s": wall, "diverged": est["diverged"]}),
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
