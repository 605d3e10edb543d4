"""``bench check``'s servo verdict from the body's rolls, with the turns scripted, and its
watchdog verdict from a body on a simulated clock."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Any, cast

import pytest

from tumblebot.host import bench as B
from tumblebot.host.mocap import Pose

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


class _Agent:
    def __init__(self) -> None:
        self.last_telemetry: dict[str, Any] = {}

    def poll(self) -> None:
        pass


class ScriptedBody(B.Bench):
    """A bench on a simulated clock: the legs are driven until the host has been silent for
    1 s (the agent's host timeout), then the body does what ``after_stop(s)`` says, ``s``
    seconds after the stop (its roll about the leg axis, rad)."""

    def __init__(self, after_stop: Callable[[float], float]) -> None:
        super().__init__(agent=cast(Any, _Agent()), source=cast(Any, object()))
        self.clock, self.after_stop = 0.0, after_stop
        self.silent_since: float | None = None
        self.stopped_at: float | None = None

    def roll(self, t: float) -> float:
        if self.stopped_at is None or t < self.stopped_at:
            return 2.0 * t  # driven: a tumbler rolls about 2 rad/s
        return 2.0 * self.stopped_at + self.after_stop(t - self.stopped_at)

    def run(self, seconds: float, command: tuple[int, int] | None = (0, 0)) -> list[Pose]:
        if command is None and self.silent_since is None:
            self.silent_since = self.clock
        elif command is not None:
            self.silent_since = None
        poses = []
        for _ in range(round(seconds * 100)):
            self.clock += 0.01
            if self.stopped_at is None and self.silent_since is not None and self.clock - self.silent_since >= 1.0:
                self.stopped_at = self.clock
            half = self.roll(self.clock) / 2
            poses.append(Pose(self.clock, (0.0, 0.0, 0.05), (math.sin(half), 0.0, 0.0, math.cos(half))))
        return poses

    def stop(self) -> list[Pose]:
        return self.run(0.3)

    def telemetry(self, timeout: float = B.ANSWER_WAIT, accept: Any = lambda body: True) -> dict[str, Any] | None:
        stopped = self.stopped_at is not None
        body = {"host_timeouts": int(stopped), "firmware_status": {"right": 0, "left": 0} if stopped
                else {"right": 1, "left": 1}}
        return body if accept(body) else None


def test_that_a_body_that_tips_onto_a_face_after_the_watchdog_stopped_it_passes_regression_last_second_of_silence(
        ) -> None:
    """Stopped mid-tumble, the body tips 40° onto a face between 0.6 and 1.0 s after the stop:
    that is settling, not driving (the last second of a fixed silence once called it a fault)."""
    tip = math.radians(40.0)
    result = B._watchdog_check(ScriptedBody(lambda s: tip * min(max((s - 0.6) / 0.4, 0.0), 1.0)))
    assert result.ok is True, result.line()


def test_that_legs_still_turning_after_the_arduino_says_stopped_fail_the_watchdog_check() -> None:
    result = B._watchdog_check(ScriptedBody(lambda s: 2.0 * s))  # the servos are not on the pins it stopped
    assert result.ok is False
    assert "robot moved" in result.detail and "D9 and D10" in (result.fix or "")
