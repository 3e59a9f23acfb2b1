"""The verdict of ``bench precision``: Pareto fronts of each family, the cost of each at
equal error (log-log interpolation, no extrapolation), the stiffness from which implicit wins, and
the Markdown of the whole study (PRECISION.md, REPORT.md's section).

Verdict: per case and stiffness the Pareto front of each family (implicit, explicit) in (cost,
error); ``cost_at_error`` interpolates each front (log-log) at 2, 5 and 20 cm.
"""
from __future__ import annotations

import math

from . import precision
from .precision import ENSEMBLE, ERRORS, WIN_MARGIN

# -- fronts and verdict -------------------------------------------------------------------------------
def pareto_front(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The (cost, error) points no other point beats in both, by increasing cost (so decreasing error)."""
    front = []
    for c, e in sorted(p for p in points if math.isfinite(p[0]) and math.isfinite(p[1]) and p[1] > 0):
        if not front or e < front[-1][1]:
            front.append((c, e))
    return front


def cost_at_error(front: list[tuple[float, float]], error: float) -> float | None:
    """Cost of reaching ``error`` on a front (increasing cost, decreasing error): the cheapest
    point if it already reaches it, else log-log interpolation between the two points around
    it; None if no point reaches it ("not reached": no extrapolation)."""
    if not front or front[-1][1] > error:
        return None
    if front[0][1] <= error:
        return front[0][0]
    for (c0, e0), (c1, e1) in zip(front, front[1:]):
        if e0 > error >= e1:
            f = (math.log(error) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(c0) + f * (math.log(c1) - math.log(c0)))
    return None


def verdict(rows: list[dict], cost_key: str = "wall_per_sim_s", errors=ERRORS) -> list[dict]:
    """Per (case, stiffness, error): the cheapest cost of each family on its front and their ratio
    (explicit / implicit: > 1 means implicit is cheaper); ``inf`` when only implicit reaches it."""
    from ..sim.integrators import REGISTRY

    out = []
    keys = list(dict.fromkeys((r["case"], r["stiffness_scale"]) for r in rows))
    for case, scale in keys:
        fam = {}
        for implicit in (True, False):
            pts = [(r[cost_key], r["error"]) for r in rows if r["case"] == case and r["stiffness_scale"] == scale
                   and not r["diverged"] and REGISTRY[r["integrator"]].implicit == implicit]
            fam[implicit] = pareto_front(pts)
        for err in errors:
            ci, ce = cost_at_error(fam[True], err), cost_at_error(fam[False], err)
            ratio = None
            if ci is not None:
                ratio = math.inf if ce is None else ce / ci
            out.append({"case": case, "stiffness_scale": scale, "error_m": err, "implicit_cost": ci,
                        "explicit_cost": ce, "ratio": ratio})
    return out


def wins_from(verdict_rows: list[dict], case: str, error: float) -> float | None:
    """Smallest stiffness from which implicit wins (ratio >= WIN_MARGIN) at ``error`` at it and every
    larger stiffness measured; None if it does not win at the largest."""
    found = None
    for v in sorted((v for v in verdict_rows if v["case"] == case and v["error_m"] == error),
                    key=lambda v: v["stiffness_scale"]):
        if v["ratio"] is not None and v["ratio"] >= WIN_MARGIN:
            found = v["stiffness_scale"] if found is None else found
        else:
            found = None
    return found


def markdown(result: dict, heading: str = "## Work-precision at equal error") -> str:
    """The verdict tables and the references' self-check, for REPORT.md / PRECISION.md."""
    rows = result["rows"]
    out = [heading, "", precision.__doc__.split("\n\n", 1)[1].split("The verdict (")[0].strip(), "",
           "![error vs wall time per simulated second](precision_wall.png)",
           "![error vs spring passes per simulated second](precision_evals.png)", ""]
    out += [f"Cube: {'3^3, edge 1 m' if result.get('quick') else '4^3, edge 2 m'}; ensemble of "
            f"{2 if result.get('quick') else len(ENSEMBLE)} drops.", ""]
    if result.get("quick"):
        out += ["**Quick mode** (3^3 cube, short runs, few steps, one method per family): checks the machinery, "
                "not the physics at size.", ""]
    out += ["References (RK4 at 1/64 of its linear limit) and their self-check (the same at 1/32): largest centre-of-mass "
            "and shape difference [m], apex difference [m]:", "",
            "| case | stiffness | reference dt [s] | com | shape | apex |", "|---|---|---:|---:|---:|---:|"]
    for r in result["references"]:
        c = r["self_check"]
        out.append(f"| {r['case']} | x{r['stiffness_scale']:g} | {r['dt']:.3g} | {_f(c.get('com_error'))} | "
                   f"{_f(c.get('shape_error'))} | {_f(c.get('apex_diff'))} |")
    for cost_key, label in (("wall_per_sim_s", "wall s per simulated s"), ("spring_passes_per_sim_s", "spring passes per simulated s")):
        v = verdict(rows, cost_key)
        out += ["", f"### Verdict: cheapest run of each family at equal error ({label})", "",
                "Interpolated (log-log) on each family's Pareto front; 'not reached': no run of that family was "
                "that accurate. Ratio = explicit / implicit (> 1: implicit cheaper).", "",
                "| case | stiffness | " + " | ".join(f"{e * 100:g} cm: implicit / explicit / ratio" for e in ERRORS) + " |",
                "|---|---|" + "---|" * len(ERRORS)]
        for case, scale in dict.fromkeys((x["case"], x["stiffness_scale"]) for x in v):
            cells = []
            for e in ERRORS:
                x = next(x for x in v if x["case"] == case and x["stiffness_scale"] == scale and x["error_m"] == e)
                cells.append(f"{_cost(x['implicit_cost'])} / {_cost(x['explicit_cost'])} / {_ratio(x['ratio'])}")
            out.append(f"| {case} | x{scale:g} | " + " | ".join(cells) + " |")
        out += ["", "Implicit wins (by 10 % or more, at that stiffness and every larger one) from:", ""]
        for case in dict.fromkeys(x["case"] for x in v):
            parts = []
            for e in ERRORS:
                w = wins_from(v, case, e)
                parts.append(f"{e * 100:g} cm: " + (f"x{w:g}" if w is not None else "never (up to the largest stiffness)"))
            out.append(f"* {case}: " + "; ".join(parts))
    if result.get("plausibility"):
        from .plausibility import markdown as plausibility_markdown

        out += [""] + plausibility_markdown(result["plausibility"])
    return "\n".join(out) + "\n"


def _f(x):
    return "-" if x is None or not math.isfinite(x) else f"{x:.2g}"


def _cost(x):
    return "not reached" if x is None else f"{x:.3g}"


def _ratio(x):
    if x is None:
        return "-"
    return "implicit only" if math.isinf(x) else f"{x:.2f}"
