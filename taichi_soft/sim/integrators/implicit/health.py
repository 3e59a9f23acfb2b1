"""What an implicit run's own counters say about its answer: warnings, and whether it is meaningless.

The solver knows when a step went wrong: its line search found no decrease before the step
converged (the step ends at the last accepted iterate, short of the solution), the energy
clamp had to take energy out of the velocities (the step ended with more energy than it began
with), most steps stopped unconverged, or candidate body-contact pairs did not fit the pair
list (their contacts were missed). A few such steps in a long run are worth a line; when they
are a large share of the steps the result is driven by the fallback rather than by the physics,
and the run must not pass as a success (``run`` exits with ``EXIT_UNRELIABLE``).
"""

# A warning is printed when any step's solve failed or the clamp acted on at least this share of
# the steps; the answer is called meaningless at or beyond MEANINGLESS_SHARE of either.
CLAMP_WARN_SHARE = 0.05
MEANINGLESS_SHARE = 0.5
# A step whose residual at its end is above this multiple of the tolerance is counted as
# unconverged (``stats()["unconverged_steps"]``): it stopped at the iteration cap or because its
# updates stalled, and it is not the implicit solution. (A stiff cube pushed across the plane at
# 1/30 s, stopped by stalled Newton steps at 22-53 m/s^2 against a tolerance of 0.1, lost 10x the
# velocity Coulomb friction takes; converged, it lost exactly mu g h per step.)
UNCONVERGED_FACTOR = 10.0
# Unconverged steps are common at frame steps (13-62 % of the default scenes' steps at 1/30 s end
# above it, mostly around impacts), so a line is printed only when they are the majority: then
# the run shows the iteration cap, not the method.
UNCONVERGED_WARN_SHARE = 0.5


def assess(stats: dict) -> tuple[list[str], bool]:
    """(warning lines, meaningless) from an implicit integrator's ``stats()`` (any other: none)."""
    steps = int(stats.get("steps", 0))
    if steps <= 0 or "failed_solve_steps" not in stats:
        return [], False
    failed = int(stats["failed_solve_steps"])
    clamped = int(stats.get("energy_clamped_steps", 0))
    lines = []
    if failed:
        lines.append(f"{failed} of {steps} steps ended with a failed line search (no decrease of the step's "
                     f"objective before it converged; residual up to {stats['failed_solve_max_residual_m_s2']:.3g} m/s^2): "
                     "those steps stopped short of the implicit solution")
    if clamped >= CLAMP_WARN_SHARE * steps:
        lines.append(f"the energy clamp acted on {clamped} of {steps} steps (they ended with more energy than they "
                     "began with and their velocities were scaled down)")
    unconverged = int(stats.get("unconverged_steps", 0))
    if unconverged >= UNCONVERGED_WARN_SHARE * steps:
        lines.append(f"{unconverged} of {steps} steps ended with a residual above {UNCONVERGED_FACTOR:g}x the solver's "
                     "tolerance (iteration cap, or updates that stalled): their motion is an unconverged iterate's, "
                     "not the implicit solution; raise the iteration cap (solver.newton_iters / solver.iterations) "
                     "or use a smaller --dt")
    dropped = int(stats.get("body_pair_overflows", 0))
    if dropped:
        # The candidate list holds pair_list.PAIRS_PER_PARTICLE per particle; its candidates are the
        # pairs whose relative path meets (pair_list.py), so only a dense crowd of contacts fills it.
        lines.append(f"{dropped} candidate body-contact pairs did not fit the pair list and were left out of "
                     f"the steps (deepest overlap between bodies {stats.get('body_deepest_overlap_m', 0.0):.3g} m): "
                     "bodies may have passed into each other; use a smaller --dt")
    meaningless = max(failed, clamped) >= MEANINGLESS_SHARE * steps
    return lines, meaningless
