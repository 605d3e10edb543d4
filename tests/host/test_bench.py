"""``bench check``'s servo verdict from the body's rolls, with the turns scripted."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, cast

import pytest

from tumblebot.host import bench as B

TRIMS = {"right": {"neutral_us": 1500, "direction": 1}, "left": {"neutral_us": 1500, "direction": -1}}


def scripted(monkeypatch: pytest.MonkeyPatch, turns: dict[str, list[str]]) -> dict[str, int]:
    """Make each servo's turns give these verdicts in order; count the turns taken."""
    left: dict[str, Iterator[str]] = {servo: iter(v) for servo, v in turns.items()}
    taken = {servo: 0 for servo in turns}

    def turn(bench: B.Bench, servo: int, sign: int) -> tuple[str, float]:
        name = B.SERVOS[servo]
        taken[name] += 1
        verdict = next(left[name])
        return verdict, {"ok": 0.5, "reversed": -0.5, "unseen": 0.0}[verdict] * sign

    monkeypatch.setattr(B, "_turn", turn)
    return taken


def check(turns: dict[str, list[str]], monkeypatch: pytest.MonkeyPatch) -> tuple[B.Check, dict[str, int]]:
    taken = scripted(monkeypatch, turns)
    bench = B.Bench(agent=cast(Any, None), source=cast(Any, object()))
    return B._servo_check(bench, TRIMS), taken


def test_that_one_turn_that_tips_the_body_back_is_watched_again_not_called_a_fault(
        monkeypatch: pytest.MonkeyPatch) -> None:
    result, taken = check({"right": ["ok", "ok"], "left": ["reversed", "ok", "ok", "ok"]}, monkeypatch)
    assert result.ok is True, result.line()
    assert taken == {"right": 2, "left": 4}


def test_that_a_servo_reversed_both_ways_is_named_without_a_second_look(monkeypatch: pytest.MonkeyPatch) -> None:
    result, taken = check({"right": ["reversed", "reversed"], "left": ["ok", "ok"]}, monkeypatch)
    assert result.ok is False
    assert result.detail.startswith("right servo reversed")
    assert "tumblebot trim --servo right --direction -1" in (result.fix or "")
    assert taken == {"right": 2, "left": 2}


def test_that_a_servo_whose_two_looks_both_disagree_fails_the_check(monkeypatch: pytest.MonkeyPatch) -> None:
    result, taken = check({"right": ["ok", "reversed", "reversed", "ok"], "left": ["ok", "ok"]}, monkeypatch)
    assert result.ok is False
    assert "right servo did not turn both ways as told (reversed, ok)" in result.detail
    assert taken == {"right": 4, "left": 2}


def test_that_a_second_look_that_shows_the_servo_reversed_names_it(monkeypatch: pytest.MonkeyPatch) -> None:
    result, _ = check({"right": ["ok", "ok"], "left": ["ok", "reversed", "reversed", "reversed"]}, monkeypatch)
    assert result.ok is False
    assert result.detail.startswith("left servo reversed")
