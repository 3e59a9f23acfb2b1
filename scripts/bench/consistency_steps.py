"""Issue 22: convergence of an implicit solver to the explicit reference, one case of
tests/test_consistency.py (its cube, start, tolerances and reference) at several steps.

Prints, per step (run length T_END, default 0.3 s), the end-point distance [m] from RK4 at DT_REF and the first apex's relative
difference. usage (from the repository root):
  .venv/bin/python scripts/bench/consistency_steps.py CASE SCALE DT_REF NAME:DT [NAME:DT ...]
  e.g. plane_tilted 1000 2.5e-6 rk4:5e-6 implicit_euler:1e-5 implicit_euler:5e-6 implicit_euler:2.5e-6"""
import os
import sys
import time

os.environ.setdefault("TAICHI_SOFT_OPTIMIZE", "0")
sys.path.insert(0, os.getcwd())
sys.path.insert(0, os.path.join(os.getcwd(), "tests"))
import numpy as np  # noqa: E402

from taichi_soft import runtime  # noqa: E402

runtime.init("cpu", "f64")
import test_consistency as tc  # noqa: E402

run = tc.runner.__wrapped__()
case, scale = sys.argv[1], float(sys.argv[2])
# run length [s]: T_END, default 0.3 s (the docs' convergence numbers; the test itself runs 0.2 s at x1000)
tc.RUNS[case, scale] = (float(os.environ.get("T_END", "0.3")), None)
ref_h, ref_com, _ = run(case, scale, "rk4", float(sys.argv[3]))
apex_ref = tc._first_apex(ref_h)
for spec in sys.argv[4:]:
    name, dt = spec.split(":")
    t0 = time.process_time()
    h, com, st = run(case, scale, name, float(dt))
    print(f"{name} h={dt}: end {np.linalg.norm(com - ref_com) * 1e3:.1f} mm, apex {(tc._first_apex(h) - apex_ref) / apex_ref:+.2%}, "
          f"failed solves {st.get('failed_solve_steps', '-')}, clamps {st.get('energy_clamped_steps', '-')}, "
          f"{time.process_time() - t0:.1f} s CPU", flush=True)
