"""Memory stays flat over many episodes (PyBullet leaks when bodies are re-created
without ``resetSimulation``; SPEC §6)."""

import numpy as np
import psutil
import pytest

from tumblebot.sim.world.env import TumblerEnv


def rss_mb() -> float:
    return psutil.Process().memory_info().rss / 2**20


@pytest.mark.slow
@pytest.mark.parametrize(("task", "episodes", "bound_mb"), [("nav-flat", 10_000, 15.0), ("nav-terrain", 1_000, 15.0)])
def test_that_memory_stays_flat_over_many_episodes(task: str, episodes: int, bound_mb: float) -> None:
    # Short episodes (one 1/24 s step, no settling) exercise exactly what could leak:
    # resetSimulation, rebuilding the scene and the robot, stepping.
    env = TumblerEnv(task=task, episode_steps=1, step_seconds=1 / 24, settle_seconds=0.0)
    try:
        warmup = episodes // 10
        for seed in range(warmup):
            env.reset(seed=seed)
            env.step(np.array([2, 2]))
        before = rss_mb()
        for seed in range(warmup, episodes):
            env.reset(seed=seed)
            env.step(np.array([2, 2]))
        grown = rss_mb() - before
        # A 10 KB-per-episode leak would add ~90 MB over 9 000 episodes.
        assert grown < bound_mb, f"RSS grew {grown:.1f} MB over {episodes - warmup} episodes"
    finally:
        env.close()
