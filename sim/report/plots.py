"""The report's figures (matplotlib, headless)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.report.tables import StudyResult
from tumblebot.sim.world.design import BOUNDS, PARAMETERS, Design
from tumblebot.sim.world.power import energy_per_metre


# ------------------------------------------------------------------------------- plots
def _plot_objective_vs_trial(plt: Any, results: list[StudyResult]) -> Any:
    """Each study's objective per trial: screening values, promoted trials, the best full-batch value."""
    fig, axes = plt.subplots(len(results), 1, figsize=(7, 2.6 * len(results)), squeeze=False)
    for ax, r in zip(axes[:, 0], results, strict=True):
        screened = r.config.screen_batch < r.config.batch
        n = [t["number"] for t in r.trials]
        v = [t["value"] for t in r.trials]
        ax.scatter(n, v, s=8, alpha=0.5, color="C0",
                   label=f"trial, on its {r.config.screen_batch}-episode screening batch" if screened
                   else f"trial ({r.config.batch} episodes)")
        full = r.extra.get("full_batch", [])
        promoted = set(r.extra.get("promoted", []))
        marked = [(k, val) for k, val in full if k in promoted]
        if marked:
            ax.scatter(*zip(*marked, strict=True), s=40, marker="D", facecolors="none", edgecolors="C2",
                       label=f"promoted: on the full {r.config.batch}-episode batch")
        if full:
            ks, vals = zip(*full, strict=True)
            ax.step(ks, np.maximum.accumulate(vals), where="post", color="C3", label="best full-batch value so far")
        infeasible = r.extra.get("infeasible", [])
        if infeasible:  # no objective value to plot: marked along the bottom edge instead
            ax.scatter(infeasible, [0.02] * len(infeasible), s=18, marker="x", color="C1", clip_on=False,
                       transform=ax.get_xaxis_transform(), label="infeasible: legs too short to tumble (no episodes)")
        ax.axvline(r.config.startup - 0.5, color="grey", ls=":", lw=1, label="GP takes over")
        ax.set_title(f"{r.name}: {r.objective.describe()}", fontsize=9)
        ax.set_xlabel("trial")
        ax.set_ylabel("objective")
        ax.legend(fontsize=7, loc="lower right")
    return fig


def _plot_best_design_vs_trial(plt: Any, results: list[StudyResult]) -> Any:
    """Each study's best design so far, per trial."""

    fig, axes = plt.subplots(len(results), 1, figsize=(7, 2.4 * len(results)), squeeze=False)
    for ax, r in zip(axes[:, 0], results, strict=True):
        best_v, best_p, hist = -math.inf, {}, []
        for t in r.trials:
            if t["value"] > best_v:
                best_v, best_p = t["value"], t["params"]
            hist.append((t["number"], *(best_p[p] for p in PARAMETERS)))
        if hist:
            arr = np.array(hist)
            for i, p in enumerate(PARAMETERS):
                ax.step(arr[:, 0], arr[:, i + 1], where="post", label=p)
        ax.set_title(f"{r.name}: best design so far", fontsize=9)
        ax.set_xlabel("trial")
        ax.set_ylabel("m")
        ax.legend(fontsize=7, ncol=4)
    return fig


def _plot_slices(plt: Any, reference: StudyResult, slices: dict[str, Any]) -> Any:
    """One-parameter slices through the optimum, with 95 % intervals."""

    fig, axes = plt.subplots(1, 4, figsize=(12, 3), sharey=True)
    for ax, p in zip(axes, PARAMETERS, strict=True):
        rows = slices["parameters"][p]
        ok = [s for s in rows if s["objective"] is not None]
        if ok:
            xs = [s["value"] for s in ok]
            ys = [s["objective"] for s in ok]
            lo = [s["objective"] - s["ci95"][0] for s in ok]
            ax.errorbar(xs, ys, yerr=lo, fmt="o-", ms=3, capsize=2)
        bad = [s["value"] for s in rows if s["objective"] is None]
        for k, b in enumerate(bad):
            ax.axvline(b, color="grey", alpha=0.3, lw=4, label="cannot tumble" if k == 0 else None)
        ax.axvline(slices["optimum"][PARAMETERS.index(p)], color="C3", ls="--", lw=1, label="the optimum")
        ax.set_xlabel(f"{p} (m)")
        ax.legend(fontsize=7, loc="lower center")
    axes[0].set_ylabel(f"objective ({reference.name})")
    fig.suptitle("one-parameter slices through the optimum (95 % CI; grey: cannot tumble)", fontsize=9)
    return fig


def _plot_energy(plt: Any, reference: StudyResult) -> Any:
    """e(w) over two planes through the optimum."""

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    assert reference.best is not None
    bx, by, bz, bl = reference.best.design.as_tuple()
    gy, gz = np.linspace(*BOUNDS["y"], 60), np.linspace(*BOUNDS["z"], 60)
    E = np.array([[energy_per_metre(Design(bx, y, z, bl)) for y in gy] for z in gz])
    _heat(axes[0], gy, gz, E, "y (m)", "z (m)", f"e(w) at x={bx:.3f}, l={bl:.3f}")
    axes[0].plot(by, bz, "r*", ms=12, label="the optimum")
    axes[0].legend(fontsize=8, loc="upper right")
    gx, gl = np.linspace(*BOUNDS["x"], 60), np.linspace(*BOUNDS["l"], 60)
    E2 = np.array([[energy_per_metre(Design(x, by, bz, l)) for x in gx] for l in gl])  # noqa: E741
    _heat(axes[1], gx, gl, E2, "x (m)", "l (m)", f"e(w) at y={by:.3f}, z={bz:.3f}")
    axes[1].plot(bx, bl, "r*", ms=12, label="the optimum")
    axes[1].legend(fontsize=8, loc="upper right")
    return fig


def _plot_front(plt: Any, results: list[StudyResult]) -> Any:
    """Each front study: every design's mean R against its exact e(w), the front of its
    full-batch designs, and the optimum of each ξ on its iso-objective curve R = c·(e+1)^ξ."""
    fronts: dict[str, list[StudyResult]] = {}
    for r in results:
        if r.front_of is not None:
            fronts.setdefault(r.front_of, []).append(r)
    fig, axes = plt.subplots(1, len(fronts), figsize=(6.5 * len(fronts), 4.5), squeeze=False)
    for ax, (name, rows) in zip(axes[0], fronts.items(), strict=True):
        weights = rows[0].objective.weights
        trials = {t["number"]: t for t in rows[0].trials}
        S = {n: sum(weights[k] * v for k, v in t["mean_R"].items() if k in weights) for n, t in trials.items()}
        ax.scatter([trials[n]["e"] for n in S], list(S.values()), s=8, alpha=0.35, color="C0",
                   label=f"trial, on its {rows[0].config.screen_batch}-episode batch")
        full = [(trials[n]["e"], float(np.mean(rows[0].extra["full_R"][n]))) for n in rows[0].extra.get("full_R", {})
                if n in trials]
        if full:
            ax.scatter(*zip(*full, strict=True), s=30, color="C2", label=f"full {rows[0].config.batch}-episode batch")
            front, best = [], -math.inf
            for e, R in sorted(full):
                if best < R:
                    front.append((e, R))
                    best = R
            ax.step(*zip(*front, strict=True), where="post", color="C2", lw=1, label="front (full batches)")
        es = np.linspace(min(t["e"] for t in trials.values()), max(t["e"] for t in trials.values()), 100)
        for i, r in enumerate(rows):
            if r.best_trial is None or r.best_trial not in trials:
                continue
            e0 = trials[r.best_trial]["e"]
            R0 = S[r.best_trial] if r.best_trial not in rows[0].extra.get("full_R", {}) else \
                float(np.mean(rows[0].extra["full_R"][r.best_trial]))
            ax.plot(e0, R0, marker="*", ms=14, color=f"C{3 + i}", ls="none", label=f"optimum, ξ = {r.xi_label}")
            xi = r.objective.xi
            if math.isfinite(xi) and xi > 0:
                ax.plot(es, R0 * ((es + 1.0) / (e0 + 1.0)) ** xi, color=f"C{3 + i}", ls=":", lw=1)
        ax.set_ylim(min(0.0, *S.values()) if S else 0.0, 1.0)
        ax.set_xlabel("e(w) (W/m, exact)")
        ax.set_ylabel("mean R (weighted over tasks)")
        ax.set_title(f"{name}: R against e(w); dotted: equal objective through each optimum", fontsize=9)
        ax.legend(fontsize=7, loc="lower right")
    return fig


def draw_plots(results: list[StudyResult], reference: StudyResult, slices: dict[str, Any], out: Path) -> dict[str, str]:
    """Draw the report's figures into ``out``; returns name → file."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figures = {
        "objective_vs_trial": _plot_objective_vs_trial(plt, results),
        "best_design_vs_trial": _plot_best_design_vs_trial(plt, results),
        "slices": _plot_slices(plt, reference, slices),
        "energy": _plot_energy(plt, reference),
    }
    if any(r.front_of is not None for r in results):
        figures["front"] = _plot_front(plt, results)
    for name, fig in figures.items():
        fig.tight_layout()
        fig.savefig(out / f"{name}.png", dpi=110)
        plt.close(fig)
    return {name: f"{name}.png" for name in figures}


def _heat(ax: Any, xs: np.ndarray, ys: np.ndarray, E: np.ndarray, xl: str, yl: str, title: str) -> None:
    finite = np.where(np.isfinite(E), E, np.nan)
    masked = np.ma.masked_invalid(finite)
    # e(w) grows without bound near the no-tumble boundary: clip the colour scale at the 90th
    # percentile so the rest of the map is readable (values above it share the top colour).
    vmax = float(np.nanpercentile(finite, 90)) if np.isfinite(finite).any() else None
    im = ax.pcolormesh(xs, ys, masked, shading="auto", cmap="viridis", vmax=vmax)
    ax.figure.colorbar(im, ax=ax, label="e (W/m), clipped at the 90th percentile", extend="max")
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    ax.set_title(title + " (white: cannot tumble)", fontsize=9)
