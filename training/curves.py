"""Learning curves: final-state R and shaped return against environment steps."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.evaluation.stats import mean_ci95


def read_episodes(path: Path) -> dict[str, np.ndarray]:
    with path.open(newline="") as fh:
        rows = [r for r in csv.DictReader(fh)]
    return {key: np.array([float(r[key]) if r[key] else np.nan for r in rows])  # an empty cell: not recorded
            for key in ("steps", "final_R", "shaped_return")}


def _smooth(values: np.ndarray, window: int) -> np.ndarray:
    if len(values) < window:
        return values
    kernel = np.ones(window) / window
    return np.convolve(values, kernel, mode="valid")


def plot_learning_curve(csv_path: Path, png_path: Path, title: str) -> None:
    """Raw episodes faint, a moving average bold (like thesis Fig. 2.3)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = read_episodes(csv_path)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    window = max(1, min(500, len(data["steps"]) // 20))
    for ax, key, label in ((axes[0], "final_R", "final-state R (evaluation metric)"),
                           (axes[1], "shaped_return", "shaped training return")):
        steps, values = data["steps"], data[key]
        ax.plot(steps, values, color="tab:orange", alpha=0.15, linewidth=0.5)
        if len(values) >= window:
            ax.plot(steps[window - 1:], _smooth(values, window), color="tab:red", linewidth=1.8,
                    label=f"mean of {window} episodes")
            ax.legend(loc="lower right")
        ax.set_xlabel("environment steps")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    png_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png_path, dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------- lineages
class CurveError(ValueError):
    """A run folder without the files a learning curve needs."""


def _run_of_checkpoint(checkpoint: str, near: Path) -> Path | None:
    """The run folder a recorded ``init_from`` checkpoint belongs to (``RUN/latest.zip`` or
    ``RUN/checkpoints/step_N.zip``), looked up as recorded, then beside ``near``."""
    for base in (Path(checkpoint), near.parent / Path(checkpoint).parent.name / Path(checkpoint).name):
        folder = base.parent.parent if base.parent.name == "checkpoints" else base.parent
        if (folder / "episodes.csv").is_file():
            return folder
    return None


def lineage(run: Path) -> list[tuple[Path, int, str | None]]:
    """``run`` and the runs it was warm-started from, oldest first: (folder, steps the
    next run took from it or ``-1`` for all, the ``init_from`` that could not be found)."""
    import json

    chain: list[tuple[Path, int, str | None]] = []
    current: Path | None = run
    keep = -1
    seen: set[Path] = set()
    while current is not None and current.resolve() not in seen:
        seen.add(current.resolve())
        if not (current / "episodes.csv").is_file():
            raise CurveError(f"{current} has no episodes.csv (not a training run folder)")
        config_path = current / "config.json"
        config = json.loads(config_path.read_text()) if config_path.is_file() else {}
        parent = config.get("init_from")
        found = _run_of_checkpoint(parent, current) if parent else None
        chain.append((current, keep, parent if parent and found is None else None))
        keep = int(config.get("init_from_steps", 0)) if parent else -1
        current = found
    return chain[::-1]


def _plot_iterations(ax: Any, folder: Path, x: np.ndarray, values: np.ndarray, color: str) -> None:
    """A DAgger run on ``ax``: each iteration's mean final-state R with its 95 % interval
    (its episodes share one step count, so a moving average would draw steps), the
    teacher's iteration hollow, the student's filled, labelled with the student's agreement
    with its teacher."""
    with (folder / "imitation.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    ends = np.unique(x)
    means = np.array([float(np.mean(values[x == e])) for e in ends])
    half = np.array([mean - mean_ci95(values[x == e])[0] for e, mean in zip(ends, means, strict=True)])
    rows = [*rows[:len(ends)], *[{"driver": "student"}] * (len(ends) - len(rows))]  # a run stopped mid-write
    ax.plot(ends, means, color=color, linewidth=1.2, alpha=0.6)
    for e, m, h, row in zip(ends, means, half, rows, strict=True):
        student = row["driver"] == "student"
        ax.errorbar([e], [m], yerr=[h], fmt="o", color=color, capsize=3,
                    markerfacecolor=color if student else "white")
        if student and row.get("agreement"):
            ax.annotate(f"{float(row['agreement']):.3f}", (e, m), textcoords="offset points", xytext=(0, 8),
                        ha="center", fontsize=7, color=color)
    teacher = next((r["driver"] for r in rows if r["driver"] != "student"), None)
    if teacher is not None:  # a refine run's iterations are all the student's
        ax.plot([], [], "o", color=color, markerfacecolor="white", label=f"{folder.name}: {teacher} drives (DAgger 0)")
    ax.plot([], [], "o", color=color, label=f"{folder.name}: the student drives (its agreement with "
                                            f"{teacher or 'its teacher'} above each point)")


def plot_lineages(runs: list[Path], png_path: Path) -> list[list[str]]:
    """One panel per run: its final-state R over environment steps, with every run it was
    warm-started from before it on the same axis (each segment labelled, a dashed line
    where the next run starts). Returns the lineage of each run, as folder names."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chains = [lineage(r) for r in runs]
    fig, axes = plt.subplots(len(runs), 1, figsize=(10, 3.2 * len(runs)), squeeze=False)
    for ax, run, chain in zip(axes[:, 0], runs, chains, strict=True):
        offset = 0
        missing = [m for _, _, m in chain if m]
        for k, (folder, keep, _) in enumerate(chain):
            data = read_episodes(folder / "episodes.csv")
            steps, values = data["steps"], data["final_R"]
            nxt = keep
            if nxt >= 0:  # the next run started from this one's weights at step nxt
                mask = steps <= nxt
                steps, values = steps[mask], values[mask]
            x = steps + offset
            if (folder / "imitation.csv").is_file():
                _plot_iterations(ax, folder, x, values, f"C{k}")
            else:
                ax.plot(x, values, color=f"C{k}", alpha=0.12, linewidth=0.5)
                window = max(1, min(500, len(values) // 20))
                if len(values) >= window:
                    ax.plot(x[window - 1:], _smooth(values, window), color=f"C{k}", linewidth=1.8,
                            label=f"{folder.name} ({len(values)} episodes)")
            if k > 0:
                ax.axvline(offset, color="grey", ls="--", lw=1)
            offset += int(nxt if nxt >= 0 else (steps[-1] if len(steps) else 0))
        title = f"{run.name}: final-state R along its lineage"
        if missing:
            title += f" (not found: {', '.join(missing)})"
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("environment steps (all runs of the lineage)")
        ax.set_ylabel("final-state R")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    png_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png_path, dpi=110)
    plt.close(fig)
    return [[f.name for f, _, _ in chain] for chain in chains]
