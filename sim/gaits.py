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

GAITS: dict[str, Gait] = {
    "forward": lambda step, rng: (FORWARD, FORWARD),
    "reverse": lambda step, rng: (REVERSE, REVERSE),
    "alternate": lambda step, rng: (FORWARD, STOP) if step % 2 == 0 else (STOP, FORWARD),
    "pulse": lambda step, rng: (FORWARD, FORWARD) if step % 2 == 0 else (STOP, STOP),
    "spin": lambda step, rng: (FORWARD, REVERSE),
    "stop": lambda step, rng: (STOP, STOP),
    "random": lambda step, rng: (int(rng.integers(3)), int(rng.integers(3))),
}

GAIT_HELP: dict[str, str] = {
    "forward": "both legs full forward every step",
    "reverse": "both legs full reverse every step",
    "alternate": "right leg forward, then left leg forward, alternating",
    "pulse": "both legs forward for a step, then a step stopped",
    "spin": "legs in opposite directions (turn on the spot)",
    "stop": "both legs stopped",
    "random": "a uniformly random action every step",
}


def get_gait(name: str) -> Gait:
    try:
        return GAITS[name]
    except KeyError:
        raise UnknownGaitError(f"unknown gait {name!r}; choose one of: {', '.join(GAITS)}") from None
