"""Learning curves: final-state R and shaped return against environment steps."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np


def read_episodes(path: Path) -> dict[str, np.ndarray]:
    with path.open(newline="") as fh:
        rows = [r for r in csv.DictReader(fh)]
    return {key: np.array([float(r[key]) for r in rows]) for key in ("steps", "final_R", "shaped_return")}


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
