"""tumblebot: simulate, train, optimise and deploy two-legged tumbling robots.

Importing ``tumblebot`` registers the four Gymnasium environments
(``tumblebot/NavFlat-v0``, ``tumblebot/NavTerrain-v0``, ``tumblebot/DistanceFlat-v0``,
``tumblebot/Incline-v0``) when Gymnasium is installed. Registration only records entry
points; PyBullet is imported when an environment is made. On a Raspberry Pi, where only
the agent is installed, importing ``tumblebot`` costs nothing.
"""

from __future__ import annotations

from tumblebot.errors import TumblebotError

__version__ = "0.1.0"
__all__ = ["TumblebotError", "__version__"]


def _register_envs() -> None:
    try:
        import gymnasium
    except ImportError:  # the agent-only install has no gymnasium
        return
    from tumblebot.sim.tasks import TASKS

    for task in TASKS.values():
        if task.env_id not in gymnasium.registry:
            gymnasium.register(
                id=task.env_id,
                entry_point="tumblebot.sim.env:TumblerEnv",
                kwargs={"task": task.name},
                max_episode_steps=None,
            )


_register_envs()
