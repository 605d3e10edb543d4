"""Simulation: the parametric tumbler, its four tasks, the power model and the objective.

Pure modules (``design``, ``constants``, ``mass``, ``power``, ``objective``, ``tasks``,
``gaits``, ``frames``) import numpy/scipy only; ``robot``, ``world`` and ``env`` import
PyBullet. The host may use the pure ones without pulling PyBullet in.
"""
