"""Simulation: the parametric tumbler, its four tasks, the power model and the objective.

Pure modules (``design``, ``constants``, ``mass``, ``power``, ``objective``, ``tasks``,
``gaits``, ``frames``) import numpy/scipy only; ``robot``, ``world`` and ``env`` import
PyBullet. The host may use the pure ones without pulling PyBullet in.

Importing this package registers the four tasks with Gymnasium.
"""

from __future__ import annotations


def _register_envs() -> None:
    """Register the four tasks with Gymnasium (entry points only: PyBullet is imported
    when an environment is made)."""
    try:
        import gymnasium
    except ImportError:  # an install without the sim extra
        return
    from tumblebot.sim.tasks import TASKS

    for task in TASKS.values():
        if task.env_id not in gymnasium.registry:
            gymnasium.register(id=task.env_id, entry_point="tumblebot.sim.env:TumblerEnv",
                               kwargs={"task": task.name}, max_episode_steps=None)


_register_envs()
