"""Simulation, in rooms with one-way arrows (checked by ``lint-imports``):

* :mod:`~tumblebot.sim.world`: the robot, its tasks, the physics profile, the environment;
* :mod:`~tumblebot.sim.control`: gaits, ``goto``, ONNX policies and their feature layer;
* :mod:`~tumblebot.sim.evaluation`: the episode loop, the worker pool, evaluation, the score;
* :mod:`~tumblebot.sim.optimize` and :mod:`~tumblebot.sim.report`: the design study and its report;
* :mod:`~tumblebot.sim.hardware`: the fabrication package; ``calibration``: a physics
  profile fitted to trial logs;
* ``observation`` (the layouts, shared by the world and control) and ``errors``;
* the commands' handlers: ``commands``, ``optimize_command``, ``report_command``,
  ``physics_command``, ``demo``.

The world's pure modules import numpy/scipy only; the host may use them without pulling
PyBullet in.

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
    from tumblebot.sim.world.tasks import TASKS

    for task in TASKS.values():
        if task.env_id not in gymnasium.registry:
            gymnasium.register(id=task.env_id, entry_point="tumblebot.sim.world.env:TumblerEnv",
                               kwargs={"task": task.name}, max_episode_steps=None)


_register_envs()
