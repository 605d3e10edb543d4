"""The twin's world loop without the emulator: how a hidden world's latency meets the pins."""

from __future__ import annotations

import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from tumblebot.host import twin
from tumblebot.host.twin import NEUTRAL_US, ServoHardware, _World

LATENCY = (0.030, 0.070)


class _Env:
    physics_hz = 240

    def __init__(self) -> None:
        self.randomization = SimpleNamespace(latency=LATENCY)
        self.world: Any = None
        self.changes: list[tuple[int, tuple[float, float]]] = []  #: (substep, legs' command)

    def set_leg_commands(self, right: float, left: float) -> None:
        self.changes.append((self.world.substeps, (right, left)))

    def advance(self, substeps: int) -> None:
        pass


class _Uno:
    def __init__(self) -> None:
        self.pins: tuple[float | None, float | None] = (NEUTRAL_US, NEUTRAL_US)
        self.sim_us = 0

    def widths(self) -> tuple[float | None, float | None]:
        return self.pins


def _world(seed: int) -> tuple[_World, _Env, _Uno]:
    env, uno = _Env(), _Uno()
    world = _World(env, uno, ("127.0.0.1", 9), "tumbler", 60.0, ServoHardware())
    world.publish["on"] = False
    world.latency_rng = np.random.default_rng(seed)
    env.world = world
    return world, env, uno


@pytest.fixture(autouse=True)
def _clock(monkeypatch: pytest.MonkeyPatch) -> None:
    """The world's real time, set by the test and never waited for."""
    monkeypatch.setattr(twin, "time", SimpleNamespace(monotonic=lambda: 0.0, time=time.time))


def _run(world: _World, substeps: int) -> None:
    """Simulate ``substeps`` substeps, one catch-up each."""
    for _ in range(substeps):
        world.wall0 = -(world.substeps + 1.5) * world.dt  # one substep is due
        assert world.catch_up()


def test_that_the_two_pins_of_one_command_share_the_hidden_worlds_latency() -> None:
    """The firmware's two pins can change in different reads of one servo frame; the radio
    delays the command they carry as a whole. With a draw per pin change the second leg
    started up to 40 ms after the first (the later of two draws), turning the robot off
    the line a pure replay of the same command drives."""
    hardware = ServoHardware()
    fast, back = NEUTRAL_US + 400.0, NEUTRAL_US - 400.0
    both = hardware.commands((fast, back))
    lo, hi = (round(v * _Env.physics_hz) for v in LATENCY)
    delays = []
    for seed in range(40):
        world, env, uno = _world(seed)
        _run(world, 5)
        uno.pins = (fast, NEUTRAL_US)  # the right pin's new pulse is read first ...
        _run(world, 1)
        uno.pins = (fast, back)  # ... the left one's a substep later, in the same frame
        _run(world, 40)
        (first, partial), (second, full) = env.changes
        assert partial == hardware.commands((fast, NEUTRAL_US)) and full == both
        assert second - first == 1, f"seed {seed}: the legs started {second - first} substeps apart"
        assert lo <= first - 5 <= hi
        delays.append(first)
    assert len(set(delays)) > 5  # each command still draws its own latency


def test_that_commands_a_step_apart_draw_their_own_latency() -> None:
    hardware = ServoHardware()
    fast, back = NEUTRAL_US + 400.0, NEUTRAL_US - 400.0
    gaps = set()
    for seed in range(20):
        world, env, uno = _world(seed)
        uno.pins = (fast, back)
        _run(world, 240)
        uno.pins = (NEUTRAL_US, NEUTRAL_US)
        _run(world, 40)
        (start, drive), (stop, still) = env.changes
        assert drive == hardware.commands((fast, back)) and still == (0.0, 0.0)
        gaps.add(stop - start)
    assert len(gaps) > 3  # the stop's delay is not the drive's
