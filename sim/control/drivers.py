"""What drives the robot in an episode, and which episode is which.

:class:`Driver` names an ONNX policy, a scripted gait or ``goto`` (picklable, so worker
processes rebuild it); :func:`episode_seed` is the reset seed of episode ``i`` of an
evaluation seeded ``S``, the same for every design and every number of workers (common
random numbers). The evaluation (:mod:`tumblebot.sim.evaluation.evaluate`) and the worker pool
(:mod:`tumblebot.sim.evaluation.runner`) both build on this module.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tumblebot.sim.control.gaits import get_gait
from tumblebot.sim.control.goto import NAVIGATORS, check_navigation_task, navigator
from tumblebot.sim.control.policy import OnnxPolicy, PolicyError
from tumblebot.sim.errors import SimError
from tumblebot.sim.world.physics import PhysicsProfile
from tumblebot.sim.world.tasks import get_task


@dataclass(frozen=True)
class Driver:
    """What drives the robot: ``kind`` is ``"onnx"`` (``name`` = policy path), ``"gait"``
    (``name`` = gait name, ``random`` included) or ``"goto"`` (``name`` = a hand-written
    navigation controller of :data:`~tumblebot.sim.control.goto.NAVIGATORS`, ``goto`` or
    ``plan``). Picklable, so workers can rebuild it."""

    kind: str
    name: str
    #: use a policy under a servo other than the one its model card says it was trained under
    allow_servo_mismatch: bool = False

    @classmethod
    def of_gait(cls, name: str) -> Driver:
        """``--gait NAME``: a scripted gait, or a navigation controller (``goto``, ``plan``)."""
        return cls("goto", name) if name in NAVIGATORS else cls("gait", name)

    def label(self) -> str:
        if self.kind == "onnx":
            return Path(self.name).name
        return self.name if self.kind == "goto" else f"gait:{self.name}"

    def check(self, task: str, physics: PhysicsProfile | None = None) -> None:
        """Fail fast, in this process, with one clear error. A policy is refused under
        ``physics`` other than the profile it was trained under (its model card's ``servo``;
        cards without one were trained under the default), unless ``allow_servo_mismatch``."""
        if self.kind == "onnx":
            policy = OnnxPolicy(Path(self.name), task=get_task(task).name)
            trained = PhysicsProfile.from_card(policy.card.get("servo") or {})
            if physics is not None and not self.allow_servo_mismatch and not trained.same_as(physics):
                raise PolicyError(f"policy {Path(self.name).name} was trained under the {trained.describe()}, "
                                  f"not the {physics.describe()}: train one under that world (tumblebot train "
                                  "--physics, --motor-model/--stall-torque), or pass --allow-servo-mismatch to use "
                                  "it anyway")
        elif self.kind == "goto":
            navigator(self.name)
            check_navigation_task(task)
        elif self.kind == "gait":
            get_gait(self.name)
        else:
            raise SimError(f"unknown controller kind {self.kind!r}")




def episode_seed(seed: int, index: int) -> int:
    """The reset seed of episode ``index`` in an evaluation seeded ``seed``."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1, dtype=np.uint32)[0])
