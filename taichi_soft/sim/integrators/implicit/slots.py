"""Slots of the per-step scalar fields every phase of an implicit step reads and writes.

``sc`` (f64 in either precision: its sums run over all particles): objective values, residuals, line-search state. ``ctl`` (i32): the driver's
decisions and counters. Decisions are taken in ti.funcs that write these slots, so the serial
(in-kernel) and parallel (Python-driven) drivers take the same decisions.
"""

# sc: floats
RES2 = 0  # squared residual sum_i |r_i|^2 / m_i of the last gradient [kg m^2]
RES2_0 = 1  # RES2 at the step's first gradient
RES_PREV = 2  # residual [m/s^2] of the last gradient (release margin of the active set)
F_CUR = 3  # objective at the current iterate [kg m^2]
F_TRIAL = 4  # objective at the line-search trial point
DEC = 5  # grad . (x_trial - x): first-order decrease predicted for the trial [kg m^2]
N_ACTIVE = 6  # particles held on the terrain, plus body-body pairs in contact, plus a grabbed particle
    # (grab.py), after the last gradient
ALPHA = 7  # line-search step fraction of the trial
STEP = 8  # largest particle move of the last accepted update [m]
STEP_TRIAL = 9  # largest particle move of the trial [m]
E_TRIAL = 10  # spring energy at the trial point [J]
E_CUR = 11  # spring energy at the current iterate [J]
H_START = 12  # total energy (kinetic + springs; gravity is measured from x_n) at the start of the step [J]
H_SCALE = 13  # kinetic + springs at the start: with the end's energies, the scale of the balance's round-off [J]
K_START = 14  # kinetic energy at the start [J]
LAM_CHANGE = 16  # sum |lam_candidate - lam_frozen| over held particles [kg m]
LAM_SUM = 17  # sum lam_candidate over held particles [kg m]
T_MAX = 18  # largest feasible fraction of the predicted step
BOUNCE_A = 19  # restitution: sum 1/2 m |dv|^2 [J]
BOUNCE_B = 20  # restitution: sum m v . dv [J]
K_SOLVE = 21  # kinetic energy of the solved velocities [J]
G_END = 22  # gravity energy at the end, from x_n: -sum m g . (x - x_n) [J]
K_END = 23  # kinetic energy after the collision response [J]
H2_PREV = 24  # h^2 of the previous step [s^2] (the multipliers kept for the warm start are in its units)
N_PAIRS = 25  # body-body pairs in contact after the last gradient (pairs.py; also counted in N_ACTIVE)
N_BOUNCE = 26  # held particles given a restitution velocity in this step's end
DT_STEP = 27  # h of this step [s] (the scheme's h_eff may be 2 h / 3)
N_SC = 28

# ctl: ints
DONE = 0  # 1: the step's iteration is over
UPDATE = 1  # 1: the next gradient refreezes the friction multipliers
UPDATES = 2  # outer friction updates taken in this step
ACCEPTED = 3  # the line search accepted its trial
LS_DONE = 4  # the line search is over
LS_COUNT = 5  # halvings in this line search
LS_LIMIT = 6  # most halvings in this line search
OUTER = 7  # Newton / local-global iterations taken in this step
CG = 8  # CG iterations in this step
BACKTRACKS = 9  # line-search halvings in this step
EVALS = 10  # gradient evaluations in this step
PHASE = 11  # 0: reference at x_n, 1: feasible start, 2: iterating
CLAMPED = 12  # 1: the energy clamp acted on this step
BOUNCE_LIMITED = 13  # 1: restitution was scaled down to the energy the step lost
# fast_mass_spring's L-BFGS history (local_global.py); zeroed with the rest at every step's start
LB_COUNT = 14  # pairs (s, y) kept
LB_HEAD = 15  # slot the next pair goes to
LB_UPDATES = 16  # friction refreezes (UPDATES) when the last direction was taken
LB_HELD = 17  # 1: particles were held when the last direction was taken
LB_RETRY = 18  # 1: the L-BFGS direction was no descent direction; take the global step alone
LB_RESTARTS = 19  # such restarts in this step
LS_FAILED = 20  # 1: an iteration's line search failed before the step converged (the step ended there)
N_CTL = 21

# acc: f64 sums over steps since the last stats() call
A_STEPS, A_OUTER, A_CG, A_LS, A_RES, A_UPDATES, A_CLAMPED, A_BOUNCE, A_LB_RESTARTS, A_FAILED, A_FAILED_RES, A_BDF2, \
    A_UNCONVERGED = range(13)
N_ACC = 13

START_HALVINGS = 3  # most halvings of the feasible start fraction before starting at x_n
RES_HISTORY = 64  # residuals of the last step's gradient evaluations kept for inspection
