"""The ``tumblebot physics`` command: argument parsing and dispatch only."""

from __future__ import annotations

import argparse
import json
from typing import Any


def _show(args: argparse.Namespace) -> int:
    from tumblebot.sim.world.physics import PhysicsProfile

    profile = PhysicsProfile.load(args.profile)
    if args.servo is not None:
        profile = profile.with_servo(args.servo)
    if args.json:
        print(json.dumps({**profile.to_json(), "digest": profile.digest()}))
        return 0
    print(f"physics profile {profile.name!r} (digest {profile.digest()})")
    width = max(len(k) for k in profile.to_json())
    units = {"free_speed": "rad/s", "stall_torque": "N·m", "hold_torque": "N·m", "latency": "s",
             "motor_speed_sigma": "rad/s"}
    for key, value in profile.to_json().items():
        if key != "name":
            print(f"  {key:<{width}}  {value}{' ' + units[key] if key in units else ''}")
    return 0


def add_command(sub: Any) -> None:
    """Add ``physics`` to the ``tumblebot`` parser's subcommands."""
    p = sub.add_parser("physics", help="physics profiles: the servo, floor and radio the simulator assumes",
                       description="A physics profile is everything the simulator assumes about the world outside "
                                   "the design (servo, floor friction, command latency, motor noise): a JSON file "
                                   "with flat keys in SI units, or the built-in 'thesis'.")
    psub = p.add_subparsers(dest="physics_command", required=True, metavar="{show}")
    s = psub.add_parser("show", help="print a profile", description="Print a physics profile and its digest.")
    s.add_argument("profile", help="a built-in profile (thesis) or a JSON file")
    s.add_argument("--servo", help="with this catalogue servo's free speed and stall torque (sim/world/servos.json)")
    s.add_argument("--json", action="store_true", help="print the profile as one JSON object, with its digest")
    s.set_defaults(func=_show)
