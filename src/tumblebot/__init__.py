"""tumblebot: simulate, train, optimise and deploy two-legged tumbling robots.

Importing ``tumblebot`` imports nothing else of ours: on a Raspberry Pi, where only the
agent is installed, it costs nothing, and the agent's protocol module never runs
simulator code. The four Gymnasium environments (``tumblebot/NavFlat-v0``,
``tumblebot/NavTerrain-v0``, ``tumblebot/DistanceFlat-v0``, ``tumblebot/Incline-v0``) are
registered by ``import tumblebot.sim``, or by naming the module in the id:
``gymnasium.make("tumblebot.sim:tumblebot/NavFlat-v0")``.
"""

from __future__ import annotations

from tumblebot.errors import TumblebotError

__version__ = "0.1.0"
__all__ = ["TumblebotError", "__version__"]
