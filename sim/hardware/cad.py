"""The 3D assembly with build123d (OpenCascade): STEP, glTF binary and a picture.

build123d was chosen over CadQuery for its plain-Python style (no fluent chains, shapes
are values that ``+``/``-`` combine) and because both sit on the same OpenCascade kernel
and write the same STEP. It is the ``build`` extra: nothing else in tumblebot imports it.

The assembly is in the simulator's body frame (x along the leg axis, the robot lying flat
with z up), in millimetres; the glTF file follows glTF's own convention (metres, y up).
Each solid carries the density that gives it the mass model's mass, so the assembly's
mass, centre of mass and inertia can be checked against the mass model and the URDF.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.hardware.layout import Circle, FlatPart, Rect, flat_parts, leg_plane_offset
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.mass import MassModel, combine

NUT_DIAMETER, NUT_HEIGHT = 13.0, 5.6  #: mm, an M8 nut with its washer, as one solid
HORN_DIAMETER, HORN_HEIGHT = 20.0, 2.5  #: mm, a round servo horn (the mass model's horn_stack includes it)


@dataclass
class Solid:
    name: str
    shape: Any  #: a build123d Part, mm
    density: float  #: kg/mm³
    colour: tuple[float, float, float]

    @property
    def mass(self) -> float:
        return float(self.shape.volume) * self.density


def _plate_solid(part: FlatPart) -> Any:
    """A flat part extruded along +x from x = 0 (u → y, v → z)."""
    from build123d import Box, Cylinder, Pos, Rot

    o = part.outline
    t = part.thickness
    shape = Pos(t / 2, o.u, o.v) * Box(t, o.width, o.height)
    for hole in part.holes:
        if isinstance(hole, Circle):
            shape -= Pos(t / 2, hole.u, hole.v) * Rot(0, 90, 0) * Cylinder(hole.diameter / 2, 2 * t)
        elif isinstance(hole, Rect):
            shape -= Pos(t / 2, hole.u, hole.v) * Box(2 * t, hole.width, hole.height)
    return shape


def assembly(w: Design, mass: MassModel) -> list[Solid]:
    """Every solid of the robot, legs pointing along body +z (leg angle 0)."""
    from build123d import Box, Cylinder, Pos, Rot

    parts = {p.name: p for p, _ in flat_parts(w, mass)}
    mdf, delrin = mass.plate_density * 1e-9, mass.leg_density * 1e-9
    tp, tm = mass.plate_thickness * 1e3, mass.mount_thickness * 1e3
    outer = w.x / 2 * 1e3 - mass.rod_overhang * 1e3  # a plate's outer face, |x|
    solids: list[Solid] = []
    servo = mass.servo
    length, width, height = servo.body_mm
    above = mass.servo_case_above_flange() * 1e3
    leg_part = parts["leg"]
    leg_at = outer + leg_plane_offset(mass)[0]
    for sign, side in ((1, "right"), (-1, "left")):
        mirror = Rot(0, 0, 0) if sign > 0 else Rot(0, 0, 180)  # the left side, turned about z
        plate = _plate_solid(parts[f"side_plate_{side}"])
        # u on the left plate runs along −y seen from outside, which the 180° turn about z gives
        solids.append(Solid(f"side_plate_{side}", mirror * (Pos(outer - tp, 0, 0) * plate), mdf, (0.72, 0.55, 0.35)))
        mount = _plate_solid(parts["motor_mount"])
        solids.append(Solid(f"motor_mount_{side}", mirror * (Pos(outer - tp - tm, 0, 0) * mount), delrin,
                            (0.9, 0.9, 0.85)))
        flange_face = outer - tp - tm
        centre_u = length / 2 - servo.shaft_offset_mm
        case = Pos(flange_face + above - height / 2, centre_u, 0) * Box(height, length, width)
        horn = Pos(flange_face + servo.flange_to_horn_mm - HORN_HEIGHT / 2, 0, 0) * Rot(0, 90, 0) * \
            Cylinder(HORN_DIAMETER / 2, HORN_HEIGHT)
        servo_shape = mirror * (case + horn)
        solids.append(Solid(f"servo_{side}", servo_shape, mass.servo_mass / float(servo_shape.volume),
                            (0.1, 0.1, 0.12)))
        o = leg_part.outline
        bar = Pos(leg_at + leg_part.thickness / 2, 0, o.v) * Box(leg_part.thickness, o.width, o.height)
        for hole in leg_part.holes:
            assert isinstance(hole, Circle)
            bar -= Pos(leg_at + leg_part.thickness / 2, 0, hole.v) * Rot(0, 90, 0) * \
                Cylinder(hole.diameter / 2, 2 * leg_part.thickness)
        solids.append(Solid(f"leg_{side}", mirror * bar, delrin, (0.15, 0.15, 0.15)))
    rod_area = math.pi * 4.0**2  # an M8 rod drawn as an 8 mm cylinder, at the catalogue's mass per metre
    yr, zr = (w.y / 2 - mass.rod_inset) * 1e3, (w.z / 2 - mass.rod_inset) * 1e3
    nut_mass = mass.hardware_mass / (mass.rod_count * 4)
    for k, (sy, sz) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))[: mass.rod_count]):
        rod = Pos(0, sy * yr, sz * zr) * Rot(0, 90, 0) * Cylinder(4.0, w.x * 1e3)
        solids.append(Solid(f"rod_{k + 1}", rod, mass.rod_linear_density * 1e-3 / rod_area, (0.6, 0.6, 0.62)))
        for sx in (1, -1):
            for face in (outer + NUT_HEIGHT / 2, outer - tp - NUT_HEIGHT / 2):  # outside and inside the plate
                nut = Pos(sx * face, sy * yr, sz * zr) * Rot(0, 90, 0) * \
                    (Cylinder(NUT_DIAMETER / 2, NUT_HEIGHT) - Cylinder(4.0, 2 * NUT_HEIGHT))
                solids.append(Solid("nut", nut, nut_mass / float(nut.volume), (0.7, 0.7, 0.7)))
    ex, ey, ez = (v * 1e3 for v in mass.electronics_size)
    board = Box(ex, ey, ez)
    solids.append(Solid("electronics", board, mass.electronics_mass / float(board.volume), (0.1, 0.5, 0.2)))
    return solids


def mass_properties(solids: list[Solid]) -> dict[str, Any]:
    """Mass (kg), centre of mass (m) and inertia tensor about it (kg·m²) of the assembly."""
    total, com, inertia = combine(
        [s.mass for s in solids],
        [np.array([c.X, c.Y, c.Z]) * 1e-3 for c in (s.shape.center() for s in solids)],
        [np.array(s.shape.matrix_of_inertia) * s.density * 1e-6 for s in solids])  # kg·mm² → kg·m²
    return {"mass": total, "com": com.tolist(), "inertia": inertia.tolist()}


def write_assembly(solids: list[Solid], step: Path, glb: Path) -> None:
    from build123d import Color, Compound, export_gltf, export_step

    children = []
    for s in solids:
        shape = s.shape
        shape.label = s.name
        shape.color = Color(*s.colour)
        children.append(shape)
    robot = Compound(children=children, label="tumblebot")
    export_step(robot, str(step))
    export_gltf(robot, str(glb), binary=True)


#: The assembly guide's pictures: file, the solids it shows (name prefixes), its title.
ASSEMBLY_STEPS: tuple[tuple[str, tuple[str, ...], str], ...] = (
    ("assembly-1.png", ("rod_", "nut"), "steps 1–2: rods cut, inner nuts set"),
    ("assembly-2.png", ("side_plate_right", "motor_mount_right", "servo_right"),
     "step 3: mount and servo on a plate, seen from inside"),
    ("assembly-3.png", ("rod_", "nut", "side_plate", "motor_mount", "servo"), "step 4: plates on the rods"),
    ("assembly-4.png", ("rod_", "nut", "side_plate", "motor_mount", "servo", "electronics"),
     "step 5: the electronics board"),
)


def render_steps(glb: Path, out: Path) -> list[str]:
    """One picture per step of :data:`ASSEMBLY_STEPS` (the last step is ``robot.png``), at
    the whole robot's scale; returns the file names."""
    for k, (name, keep, title) in enumerate(ASSEMBLY_STEPS):
        render_png(glb, out / name, title, keep, inside=k == 1)
    return [name for name, _, _ in ASSEMBLY_STEPS]


def _base_colour(mesh: Any) -> np.ndarray:
    """A mesh's colour for the picture: glTF keeps base colours linear, the picture is sRGB."""
    material = getattr(mesh.visual, "material", None)
    factor = getattr(material, "baseColorFactor", None)
    if factor is None:
        return np.full(3, 0.6)
    return np.clip(np.asarray(factor[:3], dtype=float) / 255.0, 0.0, 1.0) ** (1 / 2.2)


def render_png(glb: Path, png: Path, title: str, keep: tuple[str, ...] | None = None, inside: bool = False) -> None:
    """A shaded picture of the assembly from the glTF mesh (matplotlib, no screen needed);
    ``keep``: only the solids whose names start so (the axes stay the whole robot's);
    ``inside``: looking at the right plate from the body's inside, close up."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    scene: Any = trimesh.load(str(glb), force="scene")
    fig = plt.figure(figsize=(6, 5), dpi=120)
    ax = fig.add_subplot(projection="3d")
    light = np.array([0.4, -0.5, 0.77])
    triangles, colours = [], []
    for name, geom in scene.geometry.items():
        if keep is not None and not name.startswith(keep):
            continue
        mesh = geom.copy()
        mesh.apply_transform(scene.graph.get(scene.graph.geometry_nodes[name][0])[0])
        tri = mesh.vertices[mesh.faces][:, :, [0, 2, 1]]  # glTF y-up → z-up for the picture
        tri[:, :, 1] *= -1
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(normals, axis=1, keepdims=True)
        shade = 0.35 + 0.65 * np.abs((normals / np.maximum(norm, 1e-12)) @ light)
        triangles.append(tri)
        colours.append(shade[:, None] * _base_colour(mesh))
    # one collection, so that matplotlib orders the faces of all parts by depth together
    ax.add_collection3d(Poly3DCollection(np.concatenate(triangles), facecolors=np.concatenate(colours), linewidths=0))
    lo, hi = scene.bounds[0][[0, 2, 1]], scene.bounds[1][[0, 2, 1]]
    if inside:
        lo[0] = hi[0] - (hi[1] - lo[1])  # the right plate's end of the body, as deep as the plate is wide
    span = float(max(hi - lo)) / 2
    mid = (lo + hi) / 2
    ax.set_xlim(mid[0] - span, mid[0] + span)
    ax.set_ylim(-mid[1] - span, -mid[1] + span)
    ax.set_zlim(mid[2] - span, mid[2] + span)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=22, azim=150 if inside else -58)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)
