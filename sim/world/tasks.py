"""The four tasks of thesis §2.3: what differs between them, and nothing else.

A task fixes the terrain, where the robot starts, and the reward of a state. Rewards use
the corrected formulas (the thesis prints ``sqrt(vx + vy)``; the squares are
intended). This module is pure numpy: the host and the optimiser use it without PyBullet.

Tasks are posed toward the origin or along +x without loss of generality; the host maps
any goal or heading onto that frame (:mod:`tumblebot.sim.world.frames`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from tumblebot.sim.errors import UnknownTaskError

Vec3 = tuple[float, float, float]
Terrain = Literal["flat", "perlin", "incline"]
Start = Literal["ring", "origin"]


def navigation_reward(position: Vec3, velocity: Vec3) -> float:
    """``1/(1 + sqrt(vx² + vy²)) − sqrt(px² + py²)``: be at the origin, and be still."""
    return 1.0 / (1.0 + math.hypot(velocity[0], velocity[1])) - math.hypot(position[0], position[1])


def distance_reward(position: Vec3, velocity: Vec3) -> float:
    """``px − |py|``: far along +x, close to the x axis."""
    return position[0] - abs(position[1])


def incline_reward(position: Vec3, velocity: Vec3) -> float:
    """``px``: as far up the ramp as possible."""
    return position[0]


def navigation_potential(position: Vec3) -> float:
    """Progress measure for shaping: minus the distance to the origin."""
    return -math.hypot(position[0], position[1])


def distance_potential(position: Vec3) -> float:
    return position[0] - abs(position[1])


def incline_potential(position: Vec3) -> float:
    return position[0]


@dataclass(frozen=True)
class TaskSpec:
    """What defines a task.

    Attributes:
        name: short name used on the command line (``nav-flat``).
        env_id: Gymnasium id (``tumblebot/NavFlat-v0``).
        terrain: ``flat``, ``perlin`` (tiles of Perlin heights) or ``incline`` (15° ramp).
        start: ``ring`` (random direction and distance from the origin) or ``origin``.
        state_reward: the thesis reward of a state; its value at the final state is the
            evaluation metric ``R``.
        potential: a progress measure; its per-step change is the shaping term.
    """

    name: str
    env_id: str
    terrain: Terrain
    start: Start
    state_reward: Callable[[Vec3, Vec3], float]
    potential: Callable[[Vec3], float]
    description: str


TASKS: dict[str, TaskSpec] = {
    t.name: t
    for t in (
        TaskSpec(
            "nav-flat", "tumblebot/NavFlat-v0", "flat", "ring",
            navigation_reward, navigation_potential,
            "navigate to the origin on flat ground",
        ),
        TaskSpec(
            "nav-terrain", "tumblebot/NavTerrain-v0", "perlin", "ring",
            navigation_reward, navigation_potential,
            "navigate to the origin over tiles of Perlin-noise heights",
        ),
        TaskSpec(
            "distance-flat", "tumblebot/DistanceFlat-v0", "flat", "origin",
            distance_reward, distance_potential,
            "travel along +x on flat ground, staying near the x axis",
        ),
        TaskSpec(
            "incline", "tumblebot/Incline-v0", "incline", "origin",
            incline_reward, incline_potential,
            "climb a 15° ramp that starts at the origin and rises along +x",
        ),
    )
}


#: The task names, in the registry's order (the one list every command and help text uses).
TASK_NAMES: tuple[str, ...] = tuple(TASKS)
TASK_CHOICES = ", ".join(TASK_NAMES[:-1]) + " or " + TASK_NAMES[-1]  #: for help texts


def same_goal(a: str, b: str) -> bool:
    """Whether a policy trained for task ``a`` may serve task ``b``: the same reward from the
    same start, on other ground (``nav-flat`` and ``nav-terrain``). Unknown names: False."""
    if a not in TASKS or b not in TASKS:
        return False
    ta, tb = TASKS[a], TASKS[b]
    return ta.state_reward is tb.state_reward and ta.start == tb.start


def get_task(name: str) -> TaskSpec:
    """Look a task up by short name or Gymnasium id."""
    if name in TASKS:
        return TASKS[name]
    for task in TASKS.values():
        if task.env_id == name:
            return task
    raise UnknownTaskError(f"unknown task {name!r}; choose one of: {', '.join(TASKS)}")
