"""Flat drop refinement study: implicit solvers at several steps against RK4 at 1/16 of its limit.

Usage: ``python -m studies.refinement SCALE NAMES STEPS_PER_SECOND [OPTIONS_JSON]``, e.g.
``python -m studies.refinement 100 implicit_euler 60,120,240,480,960`` (the 4^3 study cube of
``bench precision``, dropped flat 2 m onto the plane, every spring's stiffness x SCALE). Prints per
step the largest centre-of-mass distance from the reference over the frames [m], the first apex of
the centre of mass above the plane [m], the time to rest [s], the median wall time of three runs [s] and the interventions the solver
counted.
"""

import json
import sys


def main(argv: list[str]) -> None:
    from taichi_soft import runtime

    runtime.init("cpu", "f64")
    from taichi_soft.bench import precision as P

    scale, names = float(argv[0]), argv[1].split(",")
    dts = [1.0 / float(m) for m in argv[2].split(",")]
    options = json.loads(argv[3]) if len(argv) > 3 else {}
    scene, sets, t_end = P.case_runs("flat", False)[0]
    ref_sim = P.build(scene, sets, "rk4")
    base = ref_sim.model.group_k.to_numpy().copy()
    P.set_stiffness(ref_sim, scale, base)
    ref_dt = P.divide(P.stable_limit(ref_sim, "rk4") / 16)
    ref = P.trajectory(ref_sim, ref_dt, t_end)
    s = P.summary(ref)
    print(f"x{scale:g} reference rk4 dt={ref_dt:.3g} s: apex={s['apex']:.3f} m rest={s['rest_time']:.3f} s", flush=True)
    counted = ("energy_clamped_steps", "restitution_limited_steps", "unconverged_steps", "sdirk2_fallback_steps")
    for name in names:
        sim = P.build(scene, sets, name, options=options)
        P.set_stiffness(sim, scale, base)
        for dt in dts:
            run = P.trajectory(sim, dt, t_end, repeats=3)
            s, c = P.summary(run), P.compare(run, ref)
            extra = {k: run["stats"][k] for k in counted if k in run["stats"]}
            print(f"{name} 1/{1 / dt:.0f} s: com_error={c['com_error']:.3f} m apex={s['apex']:.3f} m "
                  f"rest={s['rest_time']:.3f} s wall={run['wall_s']:.3f} s {extra}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
