"""PNG plots for the benchmark report (matplotlib, headless Agg backend)."""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ..outfiles import write_atomic  # noqa: E402

MARKERS = "osD^v<>ph*"


def _by_integrator(rows):
    out = {}
    for r in rows:
        out.setdefault(r["integrator"], []).append(r)
    return out


def work_precision(rows: list[dict], path, title: str, cost_key: str = "wall_s", error_key: str = "error_final"):
    """Error against cost on log-log axes, one line per integrator; diverged points as red x at the top."""
    fig, ax = plt.subplots(figsize=(7, 5), dpi=110)
    finite = [r[error_key] for r in rows if not r["diverged"] and r[error_key] > 0]
    top = max(finite) * 10 if finite else 1.0
    for k, (name, rs) in enumerate(_by_integrator(rows).items()):
        ok = [r for r in rs if not r["diverged"] and r[error_key] > 0]
        ax.plot([r[cost_key] for r in ok], [r[error_key] for r in ok], marker=MARKERS[k % len(MARKERS)], label=name)
        bad = [r for r in rs if r["diverged"]]
        if bad:
            ax.scatter([r[cost_key] for r in bad], [top] * len(bad), marker="x", color="red", zorder=5)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel({"wall_s": "wall time [s]", "force_evals": "spring passes (force, gradient and Hessian-product evaluations)"}.get(cost_key, cost_key))
    ax.set_ylabel("RMS position error [m]")
    ax.set_title(title + ("  (red x: diverged)" if any(r["diverged"] for r in rows) else ""))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    write_atomic(Path(path), lambda tmp: fig.savefig(tmp))
    plt.close(fig)


def stability_vs_stiffness(rows: list[dict], path):
    """Largest stable dt against stiffness scale, log-log, one line per integrator."""
    fig, ax = plt.subplots(figsize=(7, 5), dpi=110)
    for k, (name, rs) in enumerate(_by_integrator(rows).items()):
        pts = sorted((r["stiffness_scale"], r["dt"]) for r in rs if r["dt"])
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker=MARKERS[k % len(MARKERS)], label=name)
        capped = [(r["stiffness_scale"], r["dt"]) for r in rs if r["dt"] and not r["bounded"]]
        if capped:
            ax.scatter([p[0] for p in capped], [p[1] for p in capped], marker="^", s=80, facecolors="none",
                       edgecolors="k", zorder=5)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("stiffness (x default 2000 N/m)")
    ax.set_ylabel("largest stable dt [s]")
    ax.set_title("Stability on the plane (open triangle: stable at the largest dt tried)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    write_atomic(Path(path), lambda tmp: fig.savefig(tmp))
    plt.close(fig)


def speed_bars(rows: list[dict], path, title: str):
    """ns per particle-step per integrator and size (log scale)."""
    sizes = sorted({r["n"] for r in rows})
    names = list(dict.fromkeys(r["integrator"] for r in rows))
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
    width = 0.8 / max(len(sizes), 1)
    for j, n in enumerate(sizes):
        vals = []
        for name in names:
            match = [r["ns_per_particle_step"] for r in rows if r["n"] == n and r["integrator"] == name]
            vals.append(match[0] if match else math.nan)
        ax.bar([i + j * width for i in range(len(names))], vals, width, label=f"n = {n}")
    ax.set_xticks([i + width * (len(sizes) - 1) / 2 for i in range(len(names))])
    ax.set_xticklabels(names, rotation=15, fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("ns per particle-step")
    ax.set_title(title)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    write_atomic(Path(path), lambda tmp: fig.savefig(tmp))
    plt.close(fig)


def precision_fronts(rows: list[dict], path, cost_key: str, cost_label: str):
    """Error [m] against cost, one panel per (case, stiffness), one line per (integrator, tolerance);
    each family's Pareto front dashed (implicit black, explicit grey)."""
    from ..sim.integrators import REGISTRY
    from .verdict import pareto_front

    cases = list(dict.fromkeys(r["case"] for r in rows))
    scales = list(dict.fromkeys(r["stiffness_scale"] for r in rows))
    if not cases:
        return
    fig, axes = plt.subplots(len(cases), len(scales), figsize=(3.6 * len(scales), 3.0 * len(cases)), dpi=90,
                             squeeze=False)
    for i, case in enumerate(cases):
        for j, scale in enumerate(scales):
            ax = axes[i][j]
            sub = [r for r in rows if r["case"] == case and r["stiffness_scale"] == scale and not r["diverged"]
                   and r["error"] > 0 and math.isfinite(r["error"])]
            series = {}
            for r in sub:
                series.setdefault((r["integrator"], r["tolerance"]), []).append(r)
            for k, ((name, tol), rs) in enumerate(series.items()):
                rs = sorted(rs, key=lambda r: r[cost_key])
                label = name if tol in ("-", None) else f"{name} ({tol})"
                ax.plot([r[cost_key] for r in rs], [r["error"] for r in rs], marker=MARKERS[k % len(MARKERS)],
                        ms=3, lw=0.8, label=label)
            for implicit, color in ((True, "black"), (False, "grey")):
                front = pareto_front([(r[cost_key], r["error"]) for r in sub if REGISTRY[r["integrator"]].implicit == implicit])
                if front:
                    ax.plot(*zip(*front), ls="--", color=color, lw=1.5)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_title(f"{case}, stiffness x{scale:g}", fontsize=9)
            ax.grid(True, which="both", alpha=0.3)
            if i == len(cases) - 1:
                ax.set_xlabel(cost_label, fontsize=8)
            if j == 0:
                ax.set_ylabel("error [m]", fontsize=8)
    handles, labels = axes[0][0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=7)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    write_atomic(Path(path), lambda tmp: fig.savefig(tmp))
    plt.close(fig)
