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
from typing import Any

import numpy as np

from tumblebot.sim.control.drivers import Driver, episode_seed
from tumblebot.sim.errors import SimError
from tumblebot.sim.evaluation.runner import EpisodeRunner
from tumblebot.sim.evaluation.stats import mean_ci95
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.physics import PhysicsProfile
from tumblebot.sim.world.power import energy_per_metre
from tumblebot.sim.world.tasks import get_task

__all__ = ["Driver", "EvalResult", "episode_seed", "evaluate", "evaluate_with", "run_lanes"]


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
    physics: PhysicsProfile = field(default_factory=PhysicsProfile)
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
        from tumblebot.sim.evaluation.score import wrap_reward

        out: dict[str, Any] = {
            "task": self.task,
            "design": self.design.as_dict(),
            "controller": self.controller,
            "motor_model": self.physics.motor_model,
            "stall_torque": self.physics.stall_torque,
            "physics": self.physics.record(),
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


def evaluate(task: str, design: Design, controller: Driver, episodes: int, seed: int = 0,
             workers: int = 1, progress: bool = False, physics: PhysicsProfile | None = None) -> EvalResult:
    """Run ``episodes`` episodes and collect the final-state rewards."""
    spec = get_task(task)
    if workers < 1:
        raise SimError(f"workers={workers} must be at least 1")
    _check(episodes, seed)
    with EpisodeRunner({spec.name: controller}, workers=workers, physics=physics) as runner:  # checks the controller
        return evaluate_with(runner, spec.name, design, episodes, seed, progress)


def evaluate_with(runner: EpisodeRunner, lane: str, design: Design, episodes: int, seed: int = 0,
                  progress: bool = False) -> EvalResult:
    """:func:`evaluate` on a runner already started: lane ``lane``'s controller and task
    (see :class:`~tumblebot.sim.evaluation.runner.EpisodeRunner`), under the runner's
    physics. The same episodes, so the same numbers, as :func:`evaluate`."""
    _check(episodes, seed)
    task, controller = runner.lane(lane)
    start = time.perf_counter()
    R, pos = run_lanes(runner, design, [lane], episodes, seed,
                       f"evaluate {task}" if progress else None)[runner.lane_key(lane)]
    return EvalResult(task, design, controller.label(), seed, R, np.hypot(pos[:, 0], pos[:, 1]), pos,
                      time.perf_counter() - start, runner.physics)


def run_lanes(runner: EpisodeRunner, design: Design, lanes: list[str], episodes: int, seed: int,
              progress: str | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """:meth:`EpisodeRunner.run_outcomes` of episodes ``0..episodes-1`` of ``lanes``
    together, under a progress bar titled ``progress`` (none if None)."""
    if progress is None:
        return runner.run_outcomes(design, lanes, 0, episodes, seed)
    from tqdm import tqdm

    with tqdm(total=episodes * len(lanes), unit="episode", desc=progress, leave=False, mininterval=1.0) as bar:
        return runner.run_outcomes(design, lanes, 0, episodes, seed, on_result=partial(bar.update, 1))


def _check(episodes: int, seed: int) -> None:
    if episodes < 1:
        raise SimError(f"episodes={episodes} must be at least 1")
    if seed < 0:
        raise SimError(f"seed={seed} must be a non-negative integer")
