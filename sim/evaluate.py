"""Evaluating a controller (an ONNX policy or a scripted gait) on a design.

Episode ``i`` of an evaluation with seed ``S`` is reset with
``episode_seed(S, i)``: the same start, terrain, masses, friction, noise and latency for
every design and whatever the number of worker processes (common random numbers; the
design is fixed, so the environment's design stream goes unused).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.constants import MAX_STALL_TORQUE, STALL_TORQUE
from tumblebot.sim.design import Design
from tumblebot.sim.errors import SimError
from tumblebot.sim.gaits import get_gait
from tumblebot.sim.goto import check_navigation_task
from tumblebot.sim.power import energy_per_metre
from tumblebot.sim.stats import mean_ci95
from tumblebot.sim.tasks import get_task


@dataclass(frozen=True)
class Controller:
    """What drives the robot: ``kind`` is ``"onnx"`` (``name`` = policy path), ``"gait"``
    (``name`` = gait name, ``random`` included) or ``"goto"`` (the closed-loop navigation
    controller of :mod:`tumblebot.sim.goto`). Picklable, so workers can rebuild it."""

    kind: str
    name: str
    #: use a policy under a servo other than the one its model card says it was trained under
    allow_servo_mismatch: bool = False

    @classmethod
    def of_gait(cls, name: str) -> Controller:
        """``--gait NAME``: a scripted gait, or ``goto``."""
        return cls("goto", "goto") if name == "goto" else cls("gait", name)

    def label(self) -> str:
        if self.kind == "onnx":
            return Path(self.name).name
        return "goto" if self.kind == "goto" else f"gait:{self.name}"

    def check(self, task: str, servo: Servo | None = None) -> None:
        """Fail fast, in this process, with one clear error. A policy is refused under a
        servo other than the one it was trained under (its model card's ``servo``; cards
        without one were trained under the default), unless ``allow_servo_mismatch``."""
        if self.kind == "onnx":
            from tumblebot.sim.policy import OnnxPolicy, PolicyError

            policy = OnnxPolicy(Path(self.name), task=get_task(task).name)
            trained = Servo.from_card(policy.card.get("servo") or {})
            if servo is not None and not self.allow_servo_mismatch and not trained.same_as(servo):
                raise PolicyError(f"policy {Path(self.name).name} was trained under the {trained.describe()}, "
                                  f"not the {servo.describe()}: train one under that servo (tumblebot train "
                                  "--motor-model/--stall-torque), or pass --allow-servo-mismatch to use it anyway")
        elif self.kind == "goto":
            check_navigation_task(task)
        elif self.kind == "gait":
            get_gait(self.name)
        else:
            raise SimError(f"unknown controller kind {self.kind!r}")


@dataclass(frozen=True)
class Servo:
    """The servo model of an evaluation: ``model`` ``"dc"`` or ``"velocity"`` and the stall
    torque in N·m (see :mod:`tumblebot.sim.env`). Part of what a result means."""

    model: str = "dc"
    stall_torque: float = STALL_TORQUE

    def __post_init__(self) -> None:
        if self.model not in ("dc", "velocity"):
            raise SimError(f"motor model {self.model!r} must be 'dc' or 'velocity'")
        if not (math.isfinite(self.stall_torque) and 0.0 < self.stall_torque <= MAX_STALL_TORQUE):
            raise SimError(f"stall torque {self.stall_torque!r} N·m must be in (0, {MAX_STALL_TORQUE:g}]")

    @classmethod
    def of(cls, model: str | None, stall_torque: float | None) -> Servo:
        """From a command line or a record, where either may be missing (the default)."""
        return cls(model or "dc", STALL_TORQUE if stall_torque is None else float(stall_torque))

    @classmethod
    def from_card(cls, data: dict[str, Any]) -> Servo:
        """A model card's, study's or twin record's ``{"motor_model", "stall_torque"}``."""
        return cls.of(data.get("motor_model"), data.get("stall_torque"))

    def same_as(self, other: Servo) -> bool:
        return self.model == other.model and math.isclose(self.stall_torque, other.stall_torque, rel_tol=1e-6)

    def describe(self) -> str:
        return f"{self.model} servo, stall torque {self.stall_torque:.3g} N·m"

    def as_dict(self) -> dict[str, Any]:
        """``{"motor_model", "stall_torque"}``: the environment's keyword arguments, and
        what records store."""
        return {"motor_model": self.model, "stall_torque": self.stall_torque}


def episode_seed(seed: int, index: int) -> int:
    """The reset seed of episode ``index`` in an evaluation seeded ``seed``."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1, dtype=np.uint32)[0])


@dataclass
class EvalResult:
    task: str
    design: Design
    controller: str
    seed: int
    R: np.ndarray  #: final-state reward per episode, in episode order
    final_distance: np.ndarray  #: planar distance to the origin at the end, m
    final_position: np.ndarray  #: (N, 3)
    wall_seconds: float
    servo: Servo = field(default_factory=Servo)
    e: float = field(init=False)

    def __post_init__(self) -> None:
        self.e = energy_per_metre(self.design)

    @property
    def episodes(self) -> int:
        return len(self.R)

    @property
    def mean_R(self) -> float:
        return float(np.mean(self.R))

    @property
    def ci95(self) -> tuple[float, float]:
        """Two-sided 95 % t interval of the mean final-state R."""
        return mean_ci95(self.R)

    def summary(self, xi: float | None = None) -> dict[str, Any]:
        from tumblebot.sim.objective import wrap_reward

        out: dict[str, Any] = {
            "task": self.task,
            "design": self.design.as_dict(),
            "controller": self.controller,
            **self.servo.as_dict(),
            "seed": self.seed,
            "episodes": self.episodes,
            "mean_R": self.mean_R,
            "ci95": list(self.ci95),
            "sd_R": float(np.std(self.R, ddof=1)) if self.episodes > 1 else 0.0,
            "median_final_distance": float(np.median(self.final_distance)),
            "e": self.e if math.isfinite(self.e) else None,
            "wall_seconds": self.wall_seconds,
        }
        if xi is not None:
            f = [wrap_reward(float(r), self.e, xi) for r in self.R]
            out["xi"] = xi
            out["mean_f"] = float(np.mean(f)) if all(map(math.isfinite, f)) else None
        return out


def evaluate(task: str, design: Design, controller: Controller, episodes: int, seed: int = 0,
             workers: int = 1, progress: bool = False, servo: Servo | None = None) -> EvalResult:
    """Run ``episodes`` episodes and collect the final-state rewards."""
    spec = get_task(task)
    servo = servo or Servo()
    if episodes < 1:
        raise SimError(f"episodes={episodes} must be at least 1")
    if workers < 1:
        raise SimError(f"workers={workers} must be at least 1")
    if seed < 0:
        raise SimError(f"seed={seed} must be a non-negative integer")
    from tumblebot.sim.runner import EpisodeRunner

    start = time.perf_counter()
    with EpisodeRunner({spec.name: controller}, workers=workers, servo=servo) as runner:  # checks the controller
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=episodes, unit="episode", desc=f"evaluate {spec.name}", leave=False, mininterval=1.0)
        R, pos = runner.run_outcomes(design, [spec.name], 0, episodes, seed,
                                     on_result=None if bar is None else partial(bar.update, 1))[spec.name]
        if bar is not None:
            bar.close()
    return EvalResult(spec.name, design, controller.label(), seed, R, np.hypot(pos[:, 0], pos[:, 1]), pos,
                      time.perf_counter() - start, servo)
