"""The tumbler as a rigid-body model: geometry, masses and inertias from a design.

:class:`RobotModel` is the single description; :func:`build_robot` turns it into a
PyBullet multibody and :func:`to_urdf` into a URDF document, so the two never disagree.
Body frame: x along the legs' shared axis (width ``x``), y and z the side profile.
Each leg is a Delrin bar on a continuous revolute joint about x at the centre of its side
plate, extending ``l`` from the axis to the foot.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tumblebot.sim.world import constants as C
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.mass import DEFAULT_MASS_MODEL, MassModel, combine
from tumblebot.sim.world.pb import pybullet

LEG_NAMES: tuple[str, str] = ("leg_right", "leg_left")  #: joint order: +x side, −x side
LEG_GAP = 0.002  #: clearance between a side plate and its leg, m
#: Both joints turn about body −x, so "forward" on both legs rolls the robot toward body
#: +y: in the distance and incline tasks (start yaw 90°) that is world +x.
JOINT_AXIS: tuple[float, float, float] = (-1.0, 0.0, 0.0)


def _triple(values: np.ndarray) -> tuple[float, float, float]:
    a, b, c = (float(v) for v in values)
    return (a, b, c)


@dataclass(frozen=True)
class RobotModel:
    """Everything needed to simulate or export one robot (SI units).

    ``body_mass``/``body_inertia`` exclude the legs. ``leg_mass``/``leg_inertia`` are per
    leg, about the leg's own centre of mass.
    """

    design: Design
    body_mass: float
    body_inertia: tuple[float, float, float]
    leg_mass: float
    leg_inertia: tuple[float, float, float]
    leg_width: float
    leg_thickness: float
    motor_damping: float = C.MOTOR_DAMPING

    @classmethod
    def from_design(cls, design: Design, mass_model: MassModel = DEFAULT_MASS_MODEL) -> RobotModel:
        return cls(
            design=design,
            body_mass=mass_model.body_mass(design),
            body_inertia=_triple(mass_model.body_inertia(design)),
            leg_mass=mass_model.leg_mass(design),
            leg_inertia=_triple(mass_model.leg_inertia(design)),
            leg_width=mass_model.leg_width,
            leg_thickness=mass_model.leg_thickness,
        )

    def scaled(self, body_mass: float = 1.0, body_inertia: tuple[float, float, float] = (1.0, 1.0, 1.0),
               leg_mass: float = 1.0) -> RobotModel:
        """A copy with masses and inertias multiplied (domain randomisation)."""
        bi = _triple(np.multiply(self.body_inertia, body_inertia))
        li = _triple(np.multiply(self.leg_inertia, leg_mass))
        return replace(self, body_mass=self.body_mass * body_mass, body_inertia=bi,
                       leg_mass=self.leg_mass * leg_mass, leg_inertia=li)

    @property
    def total_mass(self) -> float:
        return self.body_mass + 2 * self.leg_mass

    @property
    def half_extents(self) -> tuple[float, float, float]:
        w = self.design
        return (w.x / 2, w.y / 2, w.z / 2)

    def joint_positions(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Joint origins in the body frame (right = +x side, left = −x side)."""
        off = self.design.x / 2 + LEG_GAP + self.leg_thickness / 2
        return ((off, 0.0, 0.0), (-off, 0.0, 0.0))

    def leg_half_extents(self) -> tuple[float, float, float]:
        return (self.leg_thickness / 2, self.leg_width / 2, self.design.l / 2)

    def leg_tips(self, leg_angles: tuple[float, float]) -> tuple[tuple[float, float, float], ...]:
        """Leg tips in the body frame for the given joint angles (0 = leg along body
        +z, positive angles about :data:`JOINT_AXIS`)."""
        l = self.design.l  # noqa: E741
        return tuple(
            (j[0], l * float(np.sin(a)), l * float(np.cos(a)))
            for j, a in zip(self.joint_positions(), leg_angles, strict=True)
        )


def build_robot(
    client: int,
    model: RobotModel,
    position: tuple[float, float, float],
    orientation: tuple[float, float, float, float],
    leg_angles: tuple[float, float] = (0.0, 0.0),
    lateral_friction: float = 0.9,
) -> int:
    """Create the robot in PyBullet client ``client`` and return its body id.

    Leg angles are measured about :data:`JOINT_AXIS` from the body's +z axis. Both joints get their
    default velocity motors switched off; the environment drives them.
    """
    p = pybullet()

    body_shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=model.half_extents, physicsClientId=client)
    body_visual = p.createVisualShape(p.GEOM_BOX, halfExtents=model.half_extents,
                                      rgbaColor=[0.72, 0.55, 0.35, 1.0], physicsClientId=client)
    leg_half = model.leg_half_extents()
    leg_frame = [0.0, 0.0, model.design.l / 2]
    leg_shapes = [p.createCollisionShape(p.GEOM_BOX, halfExtents=leg_half, collisionFramePosition=leg_frame,
                                         physicsClientId=client) for _ in LEG_NAMES]
    leg_visuals = [p.createVisualShape(p.GEOM_BOX, halfExtents=leg_half, visualFramePosition=leg_frame,
                                       rgbaColor=[0.15, 0.15, 0.15, 1.0], physicsClientId=client)
                   for _ in LEG_NAMES]
    identity = [0.0, 0.0, 0.0, 1.0]
    body = p.createMultiBody(
        baseMass=model.body_mass,
        baseCollisionShapeIndex=body_shape,
        baseVisualShapeIndex=body_visual,
        basePosition=position,
        baseOrientation=orientation,
        linkMasses=[model.leg_mass] * 2,
        linkCollisionShapeIndices=leg_shapes,
        linkVisualShapeIndices=leg_visuals,
        linkPositions=list(model.joint_positions()),
        linkOrientations=[identity] * 2,
        linkInertialFramePositions=[leg_frame] * 2,
        linkInertialFrameOrientations=[identity] * 2,
        linkParentIndices=[0, 0],
        linkJointTypes=[p.JOINT_REVOLUTE] * 2,
        linkJointAxis=[list(JOINT_AXIS)] * 2,
        physicsClientId=client,
    )
    for j in range(2):
        p.changeDynamics(body, j, localInertiaDiagonal=model.leg_inertia, lateralFriction=lateral_friction,
                         jointDamping=0.0, maxJointVelocity=50.0, physicsClientId=client)
        p.resetJointState(body, j, leg_angles[j], 0.0, physicsClientId=client)
    # The base last: changeDynamics(link, linearDamping=…) on a link overwrote the base's
    # inertia in PyBullet 3.2.7 (regression test: test_robot.py).
    p.changeDynamics(body, -1, localInertiaDiagonal=model.body_inertia, lateralFriction=lateral_friction,
                     linearDamping=0.0, angularDamping=0.0, physicsClientId=client)
    p.setJointMotorControlArray(body, [0, 1], p.VELOCITY_CONTROL, forces=[0.0, 0.0], physicsClientId=client)
    return int(body)


def _fmt(*values: float) -> str:
    return " ".join(f"{v:.6g}" for v in values)


def _inertial(parent: ET.Element, mass: float, inertia: tuple[float, float, float],
              xyz: tuple[float, float, float]) -> None:
    el = ET.SubElement(parent, "inertial")
    ET.SubElement(el, "origin", xyz=_fmt(*xyz), rpy="0 0 0")
    ET.SubElement(el, "mass", value=_fmt(mass))
    ET.SubElement(el, "inertia", ixx=_fmt(inertia[0]), ixy="0", ixz="0", iyy=_fmt(inertia[1]), iyz="0",
                  izz=_fmt(inertia[2]))


def _box(parent: ET.Element, tag: str, half: tuple[float, float, float], xyz: tuple[float, float, float],
         material: str | None = None) -> None:
    el = ET.SubElement(parent, tag)
    ET.SubElement(el, "origin", xyz=_fmt(*xyz), rpy="0 0 0")
    geom = ET.SubElement(el, "geometry")
    ET.SubElement(geom, "box", size=_fmt(*(2 * h for h in half)))
    if material is not None:
        ET.SubElement(el, "material", name=material)


def to_urdf(model: RobotModel, name: str = "tumblebot") -> str:
    """The robot as a URDF document (continuous joints, SI units).

    Joint ``<dynamics damping>`` carries the DC motor's viscous term ``ke²/R``; the
    motor's drive torque is not expressible in URDF and is documented in the header.
    """
    w = model.design
    robot = ET.Element("robot", name=name)
    robot.append(ET.Comment(
        f" tumblebot {w}: mass {model.total_mass:.4f} kg. Legs are continuous joints about x; "
        f"servo model: tau = ke*(V - ke*omega)/R with ke={C.KE}, R={C.WINDING_RESISTANCE}, "
        f"V={C.SUPPLY_VOLTAGE:.3f} "))
    for mat, rgba in (("mdf", "0.72 0.55 0.35 1"), ("delrin", "0.15 0.15 0.15 1")):
        m = ET.SubElement(robot, "material", name=mat)
        ET.SubElement(m, "color", rgba=rgba)
    body = ET.SubElement(robot, "link", name="body")
    _inertial(body, model.body_mass, model.body_inertia, (0.0, 0.0, 0.0))
    _box(body, "visual", model.half_extents, (0.0, 0.0, 0.0), "mdf")
    _box(body, "collision", model.half_extents, (0.0, 0.0, 0.0))
    leg_centre = (0.0, 0.0, w.l / 2)
    for leg, origin in zip(LEG_NAMES, model.joint_positions(), strict=True):
        link = ET.SubElement(robot, "link", name=leg)
        _inertial(link, model.leg_mass, model.leg_inertia, leg_centre)
        _box(link, "visual", model.leg_half_extents(), leg_centre, "delrin")
        _box(link, "collision", model.leg_half_extents(), leg_centre)
        joint = ET.SubElement(robot, "joint", name=f"{leg}_joint", type="continuous")
        ET.SubElement(joint, "parent", link="body")
        ET.SubElement(joint, "child", link=leg)
        ET.SubElement(joint, "origin", xyz=_fmt(*origin), rpy="0 0 0")
        ET.SubElement(joint, "axis", xyz=_fmt(*JOINT_AXIS))
        ET.SubElement(joint, "dynamics", damping=_fmt(model.motor_damping), friction="0")
        ET.SubElement(joint, "limit", effort=_fmt(C.STALL_TORQUE), velocity=_fmt(C.LEG_SPEED))
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def urdf_summary(model: RobotModel) -> dict[str, Any]:
    """Key figures of a model, for printing beside an exported URDF."""
    return {"design": model.design.as_tuple(), "total_mass": model.total_mass,
            "body_mass": model.body_mass, "leg_mass": model.leg_mass}


def urdf_mass_properties(model: RobotModel) -> dict[str, object]:
    """Mass (kg), centre of mass (m, body frame) and inertia tensor about it (kg·m²) of the
    whole robot as the URDF describes it, legs at angle 0 (along body +z). The fabrication
    package checks its 3D assembly against these."""
    leg_centre = np.array([0.0, 0.0, model.design.l / 2])
    total, com, inertia = combine(
        [model.body_mass, model.leg_mass, model.leg_mass],
        [np.zeros(3), *(np.array(j) + leg_centre for j in model.joint_positions())],
        [np.diag(model.body_inertia), np.diag(model.leg_inertia), np.diag(model.leg_inertia)])
    return {"mass": total, "com": com.tolist(), "inertia": inertia.tolist()}
