"""The card's comparison with the hand-written controllers: its verdict, and the second
measurement a design gets before the card calls it behind."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from tumblebot.sim.world.design import Design, tumbling_designs
from tumblebot.training import card_eval

LUCKY, LEVEL, WEAK = tumbling_designs(3, seed=5)


class _Scripted:
    """A card runner that answers, for each design and seed, the mean R given for each
    controller ("policy" for the policy), spread evenly about it; every run recorded. The
    verdict's logic is what is tested here; the real runner behind it is tested by the
    cards the export tests write."""

    def __init__(self, means: dict[tuple[Design, int], dict[str, float]]) -> None:
        self.means = means
        self.calls: list[tuple[Design, str, int, int]] = []

    def run_outcomes(self, design: Design, lanes: list[str], start: int, stop: int, seed: int,
                     on_result: Callable[[], object] | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        out = {}
        for lane in lanes:
            name = lane.removeprefix("nav:")
            self.calls.append((design, name, stop - start, seed))
            R = self.means[design, seed][name] + np.linspace(-0.05, 0.05, stop - start)
            out[lane] = (R, np.zeros((stop - start, 3)))
            for _ in range(stop - start):
                if on_result is not None:
                    on_result()
        return out


def _scripted(means: dict[tuple[Design, int], dict[str, float]]) -> Any:
    """A :class:`_Scripted` runner, typed to stand in for an EpisodeRunner."""
    return _Scripted(means)


def test_that_a_design_behind_by_chance_is_not_behind_once_measured_again() -> None:
    at_first = {"policy": 0.80, "goto": 0.78, "plan": 0.80, "plan-short": 0.79}
    means = {
        # behind at first (the strongest was lucky), level on the fresh episodes
        (LUCKY, 1): {**at_first, "plan-short": 0.85}, (LUCKY, 1001): at_first,
        (LEVEL, 1): at_first,
        # behind both times
        (WEAK, 1): {**at_first, "policy": 0.70}, (WEAK, 1001): {**at_first, "policy": 0.72},
    }
    runner = _scripted(means)
    designs = {"lucky": LUCKY, "level": LEVEL, "weak": WEAK}
    out = card_eval.hand_written_comparison(runner, designs, 48, 1, confirm=240)
    assert out["screened_behind"] == ["lucky", "weak"]
    assert out["behind"] == ["weak"] and out["bar_met"] is False
    rows = {r["label"]: r for r in out["rows"]}
    assert "confirmation" not in rows["level"]
    assert rows["lucky"]["confirmation"]["strongest"] == "plan"
    assert rows["lucky"]["confirmation"]["difference"] == pytest.approx(0.0)
    assert rows["weak"]["confirmation"]["difference"] == pytest.approx(-0.08)
    again = [c for c in runner.calls if c[3] == 1001]
    assert {c[0] for c in again} == {LUCKY, WEAK} and {c[2] for c in again} == {240}
    assert {c[1] for c in again} == {"policy", "goto", "plan", "plan-short"}
    summary = card_eval.comparison_summary(out)
    assert "NOT met (1 behind); 1 of the 2 behind at first within the bar on 240 fresh episodes" in summary
    table = card_eval.comparison_table(out)
    assert "(within the bar on 240 fresh episodes)" in table and "**behind**" in table


def test_that_without_confirmation_the_first_measurement_decides() -> None:
    means = {(LUCKY, 1): {"policy": 0.80, "goto": 0.78, "plan": 0.85, "plan-short": 0.79}}
    out = card_eval.hand_written_comparison(_scripted(means), {"lucky": LUCKY}, 48, 1)
    assert out["behind"] == out["screened_behind"] == ["lucky"]
    assert "confirmation" not in out["rows"][0]


def test_that_a_policy_ahead_on_average_and_behind_nowhere_meets_the_bar() -> None:
    means = {(d, 1): {"policy": 0.82, "goto": 0.78, "plan": 0.80, "plan-short": 0.79} for d in (LUCKY, LEVEL)}
    out = card_eval.hand_written_comparison(_scripted(means), {"a": LUCKY, "b": LEVEL}, 48, 1, confirm=240)
    assert out["bar_met"] is True and out["mean_difference"] == pytest.approx(0.02)
    assert "bar met" in card_eval.comparison_summary(out)
