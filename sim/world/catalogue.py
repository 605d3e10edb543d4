"""The servo catalogue: the one place a servo's figures live.

Each entry of ``servos.json`` (beside this file) gives a continuous-rotation servo's free
speed and stall torque at its supply voltage, its mass and its case (body, flange, mounting
holes, where the output shaft sits), and where those figures come from. The mass model
takes a servo's mass from here, the fabrication package draws its mount from here, and the
simulator's servo is the default entry, ``thesis``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cache
from importlib import resources
from typing import Any

from tumblebot.errors import TumblebotError


class CatalogueError(TumblebotError):
    """An unknown servo name, or a catalogue entry that is not usable."""


@dataclass(frozen=True)
class ServoSpec:
    """One catalogue entry. SI units, except the case dimensions (millimetres, as drawn)."""

    name: str
    part: str  #: what to buy
    free_speed: float  #: rad/s at ``voltage`` with no load
    stall_torque: float  #: N·m at ``voltage``
    voltage: float  #: V, the supply these figures are for
    mass: float  #: kg, with its horn
    body_mm: tuple[float, float, float]  #: case length (along the flange), width, height
    flange_length_mm: float  #: tip to tip of the mounting flange
    mount_holes_mm: tuple[float, float]  #: hole spacing along the length, and across the width (0: one row)
    mount_hole_diameter_mm: float
    shaft_offset_mm: float  #: output shaft centre from the nearer end of the case
    flange_to_horn_mm: float  #: from the flange's mounting face to the outer face of the horn
    horn_hole_radius_mm: float  #: the horn's screw holes, from the shaft centre
    datasheet: str
    notes: str = ""

    @classmethod
    def from_entry(cls, name: str, entry: dict[str, Any]) -> ServoSpec:
        try:
            spec = cls(name=name, part=str(entry["part"]), free_speed=float(entry["free_speed"]),
                       stall_torque=float(entry["stall_torque"]), voltage=float(entry["voltage"]),
                       mass=float(entry["mass"]), body_mm=_floats(entry["body_mm"], 3),
                       flange_length_mm=float(entry["flange_length_mm"]),
                       mount_holes_mm=_floats(entry["mount_holes_mm"], 2),
                       mount_hole_diameter_mm=float(entry["mount_hole_diameter_mm"]),
                       shaft_offset_mm=float(entry["shaft_offset_mm"]),
                       flange_to_horn_mm=float(entry["flange_to_horn_mm"]),
                       horn_hole_radius_mm=float(entry["horn_hole_radius_mm"]),
                       datasheet=str(entry["datasheet"]), notes=str(entry.get("notes", "")))
        except (KeyError, TypeError, ValueError) as exc:
            raise CatalogueError(f"servo catalogue entry {name!r} is not usable: {exc}") from None
        numbers = [spec.free_speed, spec.stall_torque, spec.voltage, spec.mass, *spec.body_mm,
                   spec.flange_length_mm, spec.mount_hole_diameter_mm, spec.flange_to_horn_mm]
        if not all(math.isfinite(v) and v > 0 for v in numbers):
            raise CatalogueError(f"servo catalogue entry {name!r} has a non-positive or non-finite figure")
        if not 0 < spec.shaft_offset_mm < spec.body_mm[0] / 2:
            raise CatalogueError(f"servo catalogue entry {name!r}: the shaft must sit in the case's nearer half")
        return spec

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "part": self.part, "free_speed": self.free_speed,
                "stall_torque": self.stall_torque, "voltage": self.voltage, "mass": self.mass,
                "datasheet": self.datasheet}


def _floats(value: Any, n: int) -> Any:
    values = tuple(float(v) for v in value)
    if len(values) != n:
        raise ValueError(f"expected {n} numbers, got {len(values)}")
    return values


@cache
def catalogue() -> dict[str, ServoSpec]:
    """Every servo in the catalogue, by name (the default first)."""
    data = json.loads(resources.files("tumblebot.sim.world").joinpath("servos.json").read_text())
    entries = {name: ServoSpec.from_entry(name, entry) for name, entry in data["servos"].items()}
    default = data["default"]
    return {default: entries[default], **entries}


def default_servo() -> ServoSpec:
    """The simulator's servo (the catalogue's default entry)."""
    return next(iter(catalogue().values()))


def servo(name: str) -> ServoSpec:
    """The catalogue entry ``name``; an unknown name gets one line listing the known ones."""
    entries = catalogue()
    if name not in entries:
        raise CatalogueError(f"unknown servo {name!r}: the catalogue has {', '.join(entries)}")
    return entries[name]
