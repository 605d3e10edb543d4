"""Defaults shared by the simulator and the command lines, importing nothing.

The command lines build their parsers from these without importing the simulator (which
registers the Gymnasium environments and takes a noticeable fraction of a second).
"""

from __future__ import annotations

#: The thesis's ξ = 3 robot (x, y, z, l) in metres: the robot built in the thesis and the
#: default design wherever one is not given.
XI3_ROBOT: tuple[float, float, float, float] = (0.292, 0.129, 0.098, 0.136)
#: The same, as the command lines take a design.
XI3_ROBOT_TEXT = ",".join(f"{v:g}" for v in XI3_ROBOT)
#: The largest servo stall torque accepted anywhere, N·m (a predecessor-like strong servo is 10).
MAX_STALL_TORQUE = 100.0
#: The policy observation layouts by name (:data:`tumblebot.sim.control.policy.LAYOUTS` defines them;
#: a test keeps the two in step).
OBSERVATION_LAYOUTS: tuple[str, ...] = ("thesis", "context", "memory", "residual", "dual", "dual-plan",
                                            "tri-plan")
