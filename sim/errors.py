"""Errors of the simulation package."""

from tumblebot.errors import TumblebotError


class SimError(TumblebotError):
    """Base class of simulation errors."""


class DesignError(SimError, ValueError):
    """A design vector that is not a valid robot (NaN, non-positive or out of bounds)."""


class UnknownTaskError(SimError, KeyError):
    """A task name that is not one of the four tasks."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it a plain line
        return str(self.args[0]) if self.args else "unknown task"


class UnknownGaitError(SimError, KeyError):
    """A scripted gait name that does not exist."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else "unknown gait"
