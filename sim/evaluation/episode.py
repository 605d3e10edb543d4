"""Running whole episodes with a scripted gait, and writing them as animations."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tumblebot.sim.errors import SimError
from tumblebot.sim.evaluation.rollout import make_actor, run_episode
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.physics import THESIS, PhysicsProfile
from tumblebot.sim.world.randomization import Randomization


@dataclass
class StepRecord:
    step: int
    action: tuple[int, int]
    position: tuple[float, float, float]
    R: float


@dataclass
class EpisodeResult:
    task: str
    gait: str
    design: Design
    seed: int
    final_R: float
    final_position: tuple[float, float, float]
    steps: list[StepRecord]
    wall_seconds: float
    frames: list[np.ndarray] = field(default_factory=list)


def run_gait_episode(
    task: str,
    design: Design,
    gait: str = "forward",
    seed: int = 0,
    randomize: bool = True,
    record: bool = False,
    physics: PhysicsProfile = THESIS,
) -> EpisodeResult:
    """One episode of ``task`` for ``design`` driven by a scripted ``gait`` (or ``goto``,
    the closed-loop navigation controller) in ``physics``'s world: with its spreads of
    floor, radio, masses and motor noise drawn from ``seed`` (``randomize``), else at their
    nominal values (:meth:`PhysicsProfile.nominal`)."""
    from tumblebot.sim.evaluation.evaluate import Driver
    from tumblebot.sim.world.env import TumblerEnv

    controller = Driver.of_gait(gait)
    controller.check(task)
    actor = make_actor(controller.kind, controller.name, task)
    randomization = physics.randomization(Randomization(design=False)) if randomize else physics.nominal()
    env = TumblerEnv(task=task, design=design, randomization=randomization,
                     render_mode="rgb_array_list" if record else None, render_size=(480, 360),
                     **physics.env_kwargs())
    try:
        steps: list[StepRecord] = []

        def record_step(step: int, action: np.ndarray, obs: np.ndarray, info: dict[str, object]) -> None:
            steps.append(StepRecord(step + 1, (int(action[0]), int(action[1])),
                                    (float(obs[0]), float(obs[1]), float(obs[2])), float(info["R"])))  # type: ignore[arg-type]

        start = time.perf_counter()
        outcome = run_episode(env, actor, seed, on_step=record_step)
        wall = time.perf_counter() - start
        frames: list[np.ndarray] = env.render() if record else []
        return EpisodeResult(task, gait, design, seed, outcome.final_R, steps[-1].position, steps, wall, frames)
    finally:
        env.close()


def write_animation(frames: list[np.ndarray], path: Path, fps: int = 10) -> None:
    """Write frames as an animated GIF (or a single PNG when ``path`` ends in .png)."""
    from PIL import Image

    if not frames:
        raise SimError("no frames to write")
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".png"):
        raise SimError(f"video file {str(path)!r} must end in .gif (or .png for one frame)")
    images = [Image.fromarray(f) for f in frames]
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".png":
        images[-1].save(path)
        return
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0,
                   optimize=False)
