"""Options of the implicit integrators, typed and documented in one place (``..options.Option``).

A scene sets them in its ``[solver]`` table or with ``--set solver.NAME=VALUE``; docs/implicit.md
lists them.
"""

from ..options import Option, int_at_least, is_bool, number_in

# Options of both solvers: contact, line search, stopping, the last-resort energy clamp.
SHARED = {
    "scheme": Option("backward_euler", lambda v: v in ("bdf2", "backward_euler"), "bdf2 or backward_euler",
                     "time discretisation: bdf2 (second order) on steps whose history is smooth and that touch "
                     "no terrain, backward Euler elsewhere; backward_euler (first order) on every step"),
    "friction_velocity": Option(1e-3, number_in(0.0, 1.0, lo_open=True), "a number in (0, 1]",
                                "sliding speed [m/s] below which friction is smoothed (static-friction creep)"),
    "velocity_tol": Option(1e-3, number_in(0.0, 1e3), "a number in [0, 1000]",
                           "stop iterating once an update moves no particle faster than this [m/s] (0: off)"),
    "line_search_iters": Option(12, int_at_least(0), "an integer >= 0",
                                "most step halvings per iteration (backtracking on the step's objective)"),
    "friction_updates": Option(10, int_at_least(0), "an integer >= 0",
                               "most outer updates of the frozen friction multipliers per step"),
    "cg_iters": Option(200, int_at_least(1), "an integer >= 1", "most CG iterations per linear solve"),
    "body_contact": Option(True, is_bool, "true or false",
                           "contact between bodies inside the step (multi-body scenes; false: bodies pass "
                           "through each other, for comparisons)"),
    "contact_stiffness": Option(1000.0, number_in(1.0, 1e8), "a number in [1, 1e8]",
                                "body-body contact penalty kappa [-]: a pair's stiffness is kappa m_ij / h^2, "
                                "so an approach stops at about 1 / (1 + kappa) of the overlap it would make"),
    "energy_clamp": Option(True, is_bool, "true or false",
                           "last resort: scale velocities back if a step still ends with more energy than it "
                           "began with (every use is counted in stats())"),
}

NEWTON = {
    **SHARED,
    "newton_iters": Option(20, int_at_least(1), "an integer >= 1", "most Newton iterations per step"),
    "newton_tol": Option(0.1, number_in(0.0, 1e3), "a number in [0, 1000]",
                         "residual [m/s^2] at which Newton stops (0: only the other tests stop it)"),
    "forcing": Option("eisenstat_walker", lambda v: v in ("eisenstat_walker", "fixed"), "eisenstat_walker or fixed",
                      "CG tolerance per Newton iteration: min(0.5, sqrt(|r_k|/|r_0|)) (Eisenstat-Walker) "
                      "or the fixed cg_tol"),
    "cg_tol": Option(1e-2, number_in(0.0, 1.0, lo_open=True), "a number in (0, 1]",
                     "relative (preconditioned) CG residual when forcing = fixed"),
}

LOCAL_GLOBAL = {
    **SHARED,
    "iterations": Option(20, int_at_least(1), "an integer >= 1", "most local/global iterations per step"),
    "tol": Option(0.1, number_in(0.0, 1e3), "a number in [0, 1000]",
                  "residual [m/s^2] at which iterations stop early (0: only the other tests stop them)"),
    "global_solver": Option("auto", lambda v: v in ("auto", "cholesky", "pcg", "by_stiffness"),
                            "auto, cholesky, pcg or by_stiffness",
                            "cholesky: prefactored skyline Cholesky (under contact see contact_solve); "
                            "pcg: matrix-free Jacobi PCG; by_stiffness: cholesky while h^2 k_max / m_min <= 10 "
                            "at the step, pcg on stiffer springs (faster impacts, worse sliding); auto: cholesky "
                            "on a CPU while the factor is small, else pcg"),
    "contact_solve": Option("auto", lambda v: v in ("auto", "scaled", "pcg"), "auto, scaled or pcg",
                            "global step with particles held on the terrain while the factor is used: "
                            "scaled: one solve with the prefactored matrix and one block-Jacobi smoothing "
                            "step (friction), filtered, its length from the step's quadratic model; "
                            "pcg: the filtered system solved by PCG to cg_tol; auto: scaled while "
                            "h^2 k_max / m_min <= 10 at the step, pcg on stiffer springs"),
    "cg_tol": Option(0.1, number_in(0.0, 1.0, lo_open=True), "a number in (0, 1]",
                     "relative CG residual of a global step (contact_solve = pcg, or global_solver = pcg)"),
    "history": Option(5, lambda v: int_at_least(0)(v) and v <= 32, "an integer in [0, 32]",
                      "L-BFGS pairs kept within a step, the global step as the initial inverse Hessian "
                      "(Liu, Bouaziz & Kavan 2017); 0: plain local/global iterations"),
}

