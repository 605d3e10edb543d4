"""The card's comparison with the hand-written controllers: its verdict, and the second
measurement a design gets before the card calls it behind."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tumblebot.sim.control.drivers import Driver
from tumblebot.sim.evaluation.evaluate import EvalResult
from tumblebot.sim.world.design import Design, tumbling_designs
from tumblebot.training import card_eval

LUCKY, LEVEL, WEAK = tumbling_designs(3, seed=5)


def _scripted(means: dict[tuple[Design, int], dict[str, float]]) -> Any:
    """An ``evaluate`` that returns, for each design and seed, the mean R given for each
    driver ("policy" for the ONNX one), spread evenly about it; every call recorded."""
    def evaluate(task: str, design: Design, driver: Driver, episodes: int, seed: int, *args: Any,
                 **kwargs: Any) -> EvalResult:
        calls.append((design, driver.name if driver.kind == "goto" else "policy", episodes, seed))
        mean = means[design, seed][calls[-1][1]]
        R = mean + np.linspace(-0.05, 0.05, episodes)
        return EvalResult(task, design, driver.label(), seed, R, np.zeros(episodes), np.zeros((episodes, 3)), 0.0)

    calls: list[tuple[Design, str, int, int]] = []
    evaluate.calls = calls  # type: ignore[attr-defined]
    return evaluate


def test_that_a_design_behind_by_chance_is_not_behind_once_measured_again(monkeypatch: pytest.MonkeyPatch) -> None:
    at_first = {"policy": 0.80, "goto": 0.78, "plan": 0.80, "plan-short": 0.79}
    means = {
        # behind at first (the strongest was lucky), level on the fresh episodes
        (LUCKY, 1): {**at_first, "plan-short": 0.85}, (LUCKY, 1001): at_first,
        (LEVEL, 1): at_first,
        # behind both times
        (WEAK, 1): {**at_first, "policy": 0.70}, (WEAK, 1001): {**at_first, "policy": 0.72},
    }
    evaluate = _scripted(means)
    monkeypatch.setattr(card_eval, "evaluate", evaluate)
    designs = {"lucky": LUCKY, "level": LEVEL, "weak": WEAK}
    out = card_eval.hand_written_comparison(Path("p.onnx"), "nav-flat", designs, 48, 1, 1, confirm=240)
    assert out["screened_behind"] == ["lucky", "weak"]
    assert out["behind"] == ["weak"] and out["bar_met"] is False
    rows = {r["label"]: r for r in out["rows"]}
    assert "confirmation" not in rows["level"]
    assert rows["lucky"]["confirmation"]["strongest"] == "plan"
    assert rows["lucky"]["confirmation"]["difference"] == pytest.approx(0.0)
    assert rows["weak"]["confirmation"]["difference"] == pytest.approx(-0.08)
    again = [c for c in evaluate.calls if c[3] == 1001]
    assert {c[0] for c in again} == {LUCKY, WEAK} and {c[2] for c in again} == {240}
    assert {c[1] for c in again} == {"policy", "goto", "plan", "plan-short"}
    summary = card_eval.comparison_summary(out)
    assert "NOT met (1 behind); 1 of the 2 behind at first within the bar on 240 fresh episodes" in summary
    table = card_eval.comparison_table(out)
    assert "(within the bar on 240 fresh episodes)" in table and "**behind**" in table


def test_that_without_confirmation_the_first_measurement_decides(monkeypatch: pytest.MonkeyPatch) -> None:
    means = {(LUCKY, 1): {"policy": 0.80, "goto": 0.78, "plan": 0.85, "plan-short": 0.79}}
    monkeypatch.setattr(card_eval, "evaluate", _scripted(means))
    out = card_eval.hand_written_comparison(Path("p.onnx"), "nav-flat", {"lucky": LUCKY}, 48, 1, 1)
    assert out["behind"] == out["screened_behind"] == ["lucky"]
    assert "confirmation" not in out["rows"][0]


def test_that_a_policy_ahead_on_average_and_behind_nowhere_meets_the_bar(monkeypatch: pytest.MonkeyPatch) -> None:
    means = {(d, 1): {"policy": 0.82, "goto": 0.78, "plan": 0.80, "plan-short": 0.79} for d in (LUCKY, LEVEL)}
    monkeypatch.setattr(card_eval, "evaluate", _scripted(means))
    out = card_eval.hand_written_comparison(Path("p.onnx"), "nav-flat", {"a": LUCKY, "b": LEVEL}, 48, 1, 1,
                                            confirm=240)
    assert out["bar_met"] is True and out["mean_difference"] == pytest.approx(0.02)
    assert "bar met" in card_eval.comparison_summary(out)
