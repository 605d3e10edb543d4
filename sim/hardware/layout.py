"""The parts of one robot as flat shapes, in millimetres, from the design and the mass model.

Every drawing, the 3D assembly and the parts list read their numbers from here, and this
module reads its own from :class:`~tumblebot.sim.world.mass.MassModel` and the servo catalogue,
so a changed constant moves the package, the mass and ``e(w)`` together.

A side plate is drawn as seen from outside the robot, in plate coordinates ``(u, v)``: ``u``
along the body's y, ``v`` along z, the origin on the leg axis (the plate's centre).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from tumblebot.sim.world.design import Design
from tumblebot.sim.world.mass import MassModel
from tumblebot.sim.world.robot import LEG_GAP

MARKER_DIAMETER = 6.4  #: mm, flat-based hemispherical mocap markers (3.2 mm tall: below the nuts)
LEG_TAIL = 7.5  #: mm of leg behind the axis, around the horn's centre screw
HORN_SCREW_HOLE = 3.2  #: mm, the horn's centre screw (M3 or #4) passes through the leg
HORN_ARM_HOLE = 2.0  #: mm, a self-tapping screw into the horn's arm

#: Mocap marker positions as fractions of the plate's half-size (u/(y/2), v/(z/2)). The set is
#: asymmetric (three on the right plate, two on the left, none mirrored), so the rigid body's
#: pose is unique; every marker sits clear of the rods' nuts and the motor mount.
MARKERS: dict[str, tuple[tuple[float, float], ...]] = {
    "right": ((-0.45, 0.70), (0.20, 0.70), (-0.10, -0.70)),
    "left": ((0.45, -0.70), (-0.35, -0.70)),
}


@dataclass(frozen=True)
class Circle:
    u: float
    v: float
    diameter: float


@dataclass(frozen=True)
class Rect:
    """An axis-aligned rectangle by its centre and size."""

    u: float
    v: float
    width: float
    height: float


@dataclass(frozen=True)
class FlatPart:
    """One laser-cut part: its outline and holes (cut) and its marks (engraved), mm."""

    name: str
    material: str
    thickness: float
    outline: Rect
    holes: tuple[Circle | Rect, ...]
    marks: tuple[Circle, ...] = field(default_factory=tuple)
    labels: tuple[tuple[float, float, str], ...] = field(default_factory=tuple)  #: engraved text (u, v, text)


def _mm(metres: float) -> float:
    return round(metres * 1e3, 6)


def servo_cutout(mass: MassModel) -> Rect:
    """The servo's case cut-out, with the output shaft on the plate's centre."""
    cu, cv = (_mm(v) for v in mass.servo_cutout())
    length = mass.servo.body_mm[0]
    return Rect(length / 2 - mass.servo.shaft_offset_mm, 0.0, cu, cv)


def servo_screws(mass: MassModel) -> tuple[Circle, ...]:
    s = mass.servo
    centre = servo_cutout(mass).u
    du, dv = s.mount_holes_mm
    rows = (0.0,) if dv == 0 else (-dv / 2, dv / 2)
    return tuple(Circle(centre + su * du / 2, sv, s.mount_hole_diameter_mm) for su in (-1, 1) for sv in rows)


def rod_holes(w: Design, mass: MassModel) -> tuple[Circle, ...]:
    hu, hv = _mm(w.y / 2 - mass.rod_inset), _mm(w.z / 2 - mass.rod_inset)
    d = _mm(mass.rod_hole_diameter)
    return tuple(Circle(su * hu, sv * hv, d) for su in (-1, 1) for sv in (-1, 1))


def marker_positions(w: Design, side: str) -> tuple[Circle, ...]:
    return tuple(Circle(round(fu * w.y / 2 * 1e3, 6), round(fv * w.z / 2 * 1e3, 6), MARKER_DIAMETER)
                 for fu, fv in MARKERS[side])


def side_plate(w: Design, mass: MassModel, side: str) -> FlatPart:
    """The ``side`` ("right": +x, "left": −x) MDF plate, seen from outside."""
    holes: tuple[Circle | Rect, ...] = (*rod_holes(w, mass), servo_cutout(mass), *servo_screws(mass))
    return FlatPart(f"side_plate_{side}", "MDF", _mm(mass.plate_thickness), Rect(0.0, 0.0, _mm(w.y), _mm(w.z)),
                    holes, marker_positions(w, side),
                    ((0.0, -_mm(w.z / 2) + 6.0, f"{side.upper()} (outside)"),))


def motor_mount(mass: MassModel) -> FlatPart:
    """The Delrin motor mount: it sits on the plate's inner face under the servo's flange."""
    mu, mv = (_mm(v) for v in mass.mount_outline())
    centre = servo_cutout(mass).u
    return FlatPart("motor_mount", "Delrin", _mm(mass.mount_thickness), Rect(centre, 0.0, mu, mv),
                    (servo_cutout(mass), *servo_screws(mass)))


def leg(w: Design, mass: MassModel) -> FlatPart:
    """A leg: ``l`` from the axis (the centre hole) to the foot, plus a tail around the axis."""
    length = _mm(w.l) + LEG_TAIL
    width = _mm(mass.leg_width)
    outline = Rect(0.0, (_mm(w.l) - LEG_TAIL) / 2, width, length)
    holes = (Circle(0.0, 0.0, HORN_SCREW_HOLE), Circle(0.0, mass.servo.horn_hole_radius_mm, HORN_ARM_HOLE))
    return FlatPart("leg", "Delrin", _mm(mass.leg_thickness), outline, holes)


def leg_plane_offset(mass: MassModel) -> tuple[float, float]:
    """Where a leg's inner face sits outside the plate's outer face, mm: (as built on the
    servo's horn, as simulated)."""
    built = mass.servo.flange_to_horn_mm - _mm(mass.plate_thickness + mass.mount_thickness)
    simulated = _mm(mass.rod_overhang + LEG_GAP)
    return (round(built, 3), round(simulated, 3))


def flat_parts(w: Design, mass: MassModel) -> list[tuple[FlatPart, int]]:
    """Every laser-cut part with how many to cut."""
    return [(side_plate(w, mass, "right"), 1), (side_plate(w, mass, "left"), 1), (motor_mount(mass), 2),
            (leg(w, mass), 2)]


def marker_table(w: Design, mass: MassModel) -> list[tuple[str, float, float, float]]:
    """Mocap marker base centres in the body frame (mm): on the plates' outer faces."""
    outer = (w.x / 2 - mass.rod_overhang) * 1e3
    rows = []
    for side, sign in (("right", 1), ("left", -1)):
        for k, (fu, fv) in enumerate(MARKERS[side]):
            u, v = fu * w.y / 2 * 1e3, fv * w.z / 2 * 1e3
            rows.append((f"{side}_{k + 1}", round(sign * outer, 3), round(sign * u, 3), round(v, 3)))
    return rows
