"""The world: the parametric robot (design, masses, power), its four tasks and their
scenes, the physics profile of everything outside the design, and the Gymnasium
environment that steps it all in PyBullet.

Nothing here imports :mod:`tumblebot.sim.control` or :mod:`tumblebot.sim.evaluation`:
the world does not know who drives it. ``design``, ``constants``, ``mass``, ``power``,
``tasks`` and ``frames`` import numpy and scipy only; ``robot``, ``scene`` and ``env``
import PyBullet.
"""
