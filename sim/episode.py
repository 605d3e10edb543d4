"""Running whole episodes with a scripted gait, and writing them as animations."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tumblebot.sim.constants import STALL_TORQUE
from tumblebot.sim.design import Design
from tumblebot.sim.errors import SimError
from tumblebot.sim.gaits import get_gait
from tumblebot.sim.goto import GotoController, check_navigation_task
from tumblebot.sim.randomization import Randomization


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
    randomization: Randomization | None = None,
    motor_model: str = "dc",
    record: bool = False,
    stall_torque: float = STALL_TORQUE,
) -> EpisodeResult:
    """One episode of ``task`` for ``design`` driven by a scripted ``gait`` (or ``goto``,
    the closed-loop navigation controller)."""
    from tumblebot.sim.env import TumblerEnv

    goto: GotoController | None = None
    if gait == "goto":
        check_navigation_task(task)
        goto = GotoController()
    else:
        gait_fn = get_gait(gait)
    env = TumblerEnv(task=task, design=design, randomization=randomization or Randomization.off(),
                     motor_model=motor_model,  # type: ignore[arg-type]
                     stall_torque=stall_torque,
                     render_mode="rgb_array_list" if record else None)
    try:
        gait_rng = np.random.default_rng(seed)
        steps: list[StepRecord] = []
        frames: list[np.ndarray] = []
        start = time.perf_counter()
        info: dict[str, object] = {}
        obs, _ = env.reset(seed=seed)
        for t in range(env.episode_steps):
            action = goto.act(obs, t) if goto is not None else gait_fn(t, gait_rng)
            obs, _, terminated, truncated, info = env.step(np.array(action))
            steps.append(StepRecord(t + 1, action, (float(obs[0]), float(obs[1]), float(obs[2])), float(info["R"])))  # type: ignore[arg-type]
            if terminated or truncated:
                break
        wall = time.perf_counter() - start
        if record:
            frames = env.render()
        return EpisodeResult(task, gait, design, seed, float(info["final_R"]),  # type: ignore[arg-type]
                             steps[-1].position, steps, wall, frames)
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
