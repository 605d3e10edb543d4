"""Fixed scripted gaits: open-loop action sequences, the baselines a policy must beat.

An action is ``(right, left)`` with 0 = full reverse, 1 = stop, 2 = full forward, the
encoding of the environments' ``MultiDiscrete([3, 3])`` action space.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from tumblebot.sim.errors import UnknownGaitError

Action = tuple[int, int]
Gait = Callable[[int, np.random.Generator], Action]

REVERSE, STOP, FORWARD = 0, 1, 2

#: The identification run (``tumblebot bench excite``): 20 steps that show what the
#: simulator's world assumptions do to the robot's motion: drives both ways, spins both
#: ways, one leg at a time, and stops after motion (what a stopped servo holds).
EXCITATION: tuple[Action, ...] = (
    *[(FORWARD, FORWARD)] * 4, *[(FORWARD, REVERSE)] * 2, (STOP, STOP),
    *[(REVERSE, REVERSE)] * 4, *[(REVERSE, FORWARD)] * 2, (STOP, STOP),
    *[(FORWARD, STOP)] * 2, *[(STOP, FORWARD)] * 2, *[(FORWARD, FORWARD)] * 2)

GAITS: dict[str, Gait] = {
    "forward": lambda step, rng: (FORWARD, FORWARD),
    "reverse": lambda step, rng: (REVERSE, REVERSE),
    "alternate": lambda step, rng: (FORWARD, STOP) if step % 2 == 0 else (STOP, FORWARD),
    "pulse": lambda step, rng: (FORWARD, FORWARD) if step % 2 == 0 else (STOP, STOP),
    "spin": lambda step, rng: (FORWARD, REVERSE),
    "stop": lambda step, rng: (STOP, STOP),
    "random": lambda step, rng: (int(rng.integers(3)), int(rng.integers(3))),
    "excite": lambda step, rng: EXCITATION[step % len(EXCITATION)],
}

GAIT_HELP: dict[str, str] = {
    "forward": "both legs full forward every step",
    "reverse": "both legs full reverse every step",
    "alternate": "right leg forward, then left leg forward, alternating",
    "pulse": "both legs forward for a step, then a step stopped",
    "spin": "legs in opposite directions (turn on the spot)",
    "stop": "both legs stopped",
    "random": "a uniformly random action every step",
    "excite": "the identification run: drives and spins both ways, one leg at a time, stops (20 steps)",
}


def get_gait(name: str) -> Gait:
    try:
        return GAITS[name]
    except KeyError:
        raise UnknownGaitError(f"unknown gait {name!r}; choose one of: {', '.join(GAITS)}") from None


class GaitPolicy:
    """A gait as a controller of the deployed stack (``tumblebot trial run --gait``): the
    observation is ignored; ``reset()`` starts the gait again (``random`` draws from ``seed``)."""

    def __init__(self, name: str, seed: int = 0) -> None:
        self.gait = get_gait(name)
        self.name, self.seed = name, seed
        self.reset()

    def reset(self) -> None:
        self.step = 0
        self.rng = np.random.default_rng(self.seed)

    def act(self, obs: object) -> Action:
        action = self.gait(self.step, self.rng)
        self.step += 1
        return action
