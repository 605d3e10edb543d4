"""What every command's parser shares: argument types, the physics and servo options, the
output checks. (The task list comes from the task registry, :mod:`tumblebot.sim.world.tasks`.)

Nothing here imports the simulator, so building the parser stays fast and works on an
install with only the ``agent`` extra.
"""

from __future__ import annotations

import argparse
import math
from typing import TypeAlias

from tumblebot.defaults import MAX_STALL_TORQUE
from tumblebot.paths import check_writable, check_writable_folder

__all__ = ["Subcommands", "add_mismatch_argument", "add_physics_argument",
           "add_servo_arguments", "check_writable", "check_writable_folder", "count", "non_negative_int",
           "number", "positive_float", "positive_int", "seed_type", "stall_torque"]

Subcommands: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"  #: what commands add their parsers to


def add_mismatch_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--allow-servo-mismatch", action="store_true",
                   help="use a policy under a servo other than the one its model card says it was trained under")


def add_physics_argument(p: argparse.ArgumentParser, what: str = "the world of every episode") -> None:
    p.add_argument("--physics", default=None, metavar="NAME|FILE",
                   help=f"physics profile: {what} (servo, floor friction, latency, motor noise): the built-in "
                        "thesis (default) or a JSON file (tumblebot physics show; docs/physics.md)")


def add_servo_arguments(p: argparse.ArgumentParser) -> None:
    # No simulator import here: building the parser stays fast (--help, bad arguments).
    add_physics_argument(p)
    p.add_argument("--motor-model", choices=("dc", "velocity"), default=None,
                   help="servo model: dc (torque falls linearly from the stall torque to zero at the free "
                        "speed) or velocity (velocity control capped at the stall torque); default the "
                        "profile's (dc)")
    p.add_argument("--stall-torque", type=stall_torque, default=None, metavar="N·m",
                   help="servo stall torque in N·m (default 0.582, the thesis's motor constants; "
                        "a predecessor-like strong servo is --motor-model velocity --stall-torque 10)")


def stall_torque(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and 0.0 < value <= MAX_STALL_TORQUE):
        raise argparse.ArgumentTypeError(f"{text} N·m must be in (0, {MAX_STALL_TORQUE:g}]")
    return value


def seed_type(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= value < 2**63:
        raise argparse.ArgumentTypeError(f"{value} must be a non-negative integer")
    return value


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be at least 1")
    return value


def non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= value <= 1000:
        raise argparse.ArgumentTypeError(f"{value} must be an integer from 0 to 1000")
    return value


def number(text: str) -> float:
    """Any float, ``inf`` and ``nan`` included, for a command that checks the value itself
    (``power``'s design parameters, ``build --xi inf``) and says what is wrong in one line."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def positive_float(text: str) -> float:
    """A finite float above 0 (a length, a step size)."""
    value = number(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text} must be a finite number above 0")
    return value


def reach_bound(text: str) -> float:
    """A bound on a body's reach ``l / r``: a finite number above 1 (where the legs just tumble the body)."""
    value = number(text)
    if not (math.isfinite(value) and value > 1.0):
        raise argparse.ArgumentTypeError(f"{text} must be above 1 (l/r is 1 where the legs just tumble the body)")
    return value


def count(text: str) -> int:
    """A non-negative integer with no upper bound (episodes, say)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} must be 0 or more")
    return value
