"""The report's plots say what they draw: every mark has a legend entry, and infeasible
trials are shown rather than dropped."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from tumblebot.sim.report.plots import _plot_energy, _plot_objective_vs_trial, _plot_slices
from tumblebot.sim.world.design import Design

OPTIMUM = Design(0.189, 0.102, 0.084, 0.108)


def _study(infeasible: list[int]) -> Any:
    config = SimpleNamespace(screen_batch=4, batch=48, startup=3)
    objective = SimpleNamespace(describe=lambda: "nav-flat=1 ξ=3")
    trials = [{"number": n, "value": 0.005 + 0.001 * n, "params": {}} for n in range(8) if n not in infeasible]
    return SimpleNamespace(name="demo", config=config, objective=objective, trials=trials,
                           extra={"full_batch": [(5, 0.01)], "promoted": [5], "infeasible": infeasible},
                           best=SimpleNamespace(design=OPTIMUM))


def _labels(fig: Any) -> set[str]:
    return {label for ax in fig.axes for label in ax.get_legend_handles_labels()[1]}


def test_that_infeasible_trials_are_marked_on_objective_vs_trial_regression_they_vanished() -> None:
    fig = _plot_objective_vs_trial(plt, [_study([1, 6])])
    ax = fig.axes[0]
    assert "infeasible: legs too short to tumble (no episodes)" in _labels(fig)
    marked = [c for c in ax.collections if c.get_label().startswith("infeasible")]
    assert [round(float(x)) for x in marked[0].get_offsets()[:, 0]] == [1, 6]
    plt.close(fig)


def test_that_the_slices_optimum_line_and_the_energy_star_have_legend_entries_regression_unlabelled_red_marks(
        ) -> None:
    rows = [{"value": v, "objective": 0.009, "ci95": [0.008, 0.01]} for v in (0.1, 0.2)]
    slices = {"parameters": {p: rows for p in ("x", "y", "z", "l")}, "optimum": list(OPTIMUM.as_tuple())}
    fig = _plot_slices(plt, _study([]), slices)
    assert all("the optimum" in ax.get_legend_handles_labels()[1] for ax in fig.axes)
    plt.close(fig)
    fig = _plot_energy(plt, _study([]))
    drawn = [ax for ax in fig.axes if ax.get_legend() is not None]
    assert len(drawn) == 2 and all("the optimum" in ax.get_legend_handles_labels()[1] for ax in drawn)
    plt.close(fig)
