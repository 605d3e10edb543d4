"""Foxglove's well-known message types for trial logs, so a trial opens as a 3D scene.

Foxglove recognises a message by its schema *name* (``foxglove.FrameTransform``, …) and
decodes JSON messages by the schema's fields. The JSON schemas here are written out from
Foxglove's published message definitions (https://docs.foxglove.dev/docs/sdk/schemas),
only the fields we send, built from a few shared pieces. What a trial log carries beside
our own ``tumblebot.*`` topics (``host/triallog.py``):

* ``/tf`` (``foxglove.FrameTransform``): ``lab`` → ``robot``, one per mocap pose;
* ``/robot/pose`` (``foxglove.PoseInFrame``): the same pose, for plots and the pose panel;
* ``/robot/model`` (``foxglove.SceneUpdate``): the body as a box ``x × y × z`` and the two
  legs as plates of length ``l`` at its sides, in the ``robot`` frame (frame-locked, so it
  moves with ``/tf``). The legs are drawn at rest, pointing down: the pose stream carries
  no servo angles;
* ``/scene`` (``foxglove.SceneUpdate``): the setpoint (a green disc), the circle the start
  points lie on (a grey line loop) and this trial's start point, in the ``lab`` frame.

``docs/foxglove-layout.json`` is a Foxglove layout with a 3D panel following ``robot``, a
plot of the distance to the setpoint and the raw messages.
"""

from __future__ import annotations

import math
from typing import Any

LAB, ROBOT = "lab", "robot"


# ----------------------------------------------------------------------------- schemas
def _obj(title: str, description: str, **properties: dict[str, Any]) -> dict[str, Any]:
    return {"title": title, "description": description, "type": "object", "properties": properties}


def _num(description: str) -> dict[str, Any]:
    return {"type": "number", "description": description}


def _time(description: str) -> dict[str, Any]:
    return {"type": "object", "title": "time", "description": description, "properties": {
        "sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}


def _vector3(description: str) -> dict[str, Any]:
    return _obj("foxglove.Vector3", description, x=_num("x"), y=_num("y"), z=_num("z"))


def _quaternion(description: str) -> dict[str, Any]:
    return _obj("foxglove.Quaternion", description, x=_num("x"), y=_num("y"), z=_num("z"), w=_num("w"))


def _pose(description: str) -> dict[str, Any]:
    return _obj("foxglove.Pose", description, position=_vector3("position"),
                orientation=_quaternion("orientation"))


def _color(description: str) -> dict[str, Any]:
    return _obj("foxglove.Color", description, r=_num("red, 0-1"), g=_num("green, 0-1"), b=_num("blue, 0-1"),
                a=_num("alpha, 0-1"))


def _array(item: dict[str, Any], description: str) -> dict[str, Any]:
    return {"type": "array", "items": item, "description": description}


def _scene_update() -> dict[str, Any]:
    cube = _obj("foxglove.CubePrimitive", "a box", pose=_pose("centre and orientation"),
                size=_vector3("size along each axis"), color=_color("colour"))
    cylinder = _obj("foxglove.CylinderPrimitive", "a cylinder or disc", pose=_pose("centre and orientation"),
                    size=_vector3("bounding-box size"), bottom_scale=_num("bottom radius scale"),
                    top_scale=_num("top radius scale"), color=_color("colour"))
    line = _obj("foxglove.LinePrimitive", "a line strip, loop or list", type={
        "title": "foxglove.LineType", "oneOf": [{"title": "LINE_STRIP", "const": 0}, {"title": "LINE_LOOP", "const": 1},
                                                {"title": "LINE_LIST", "const": 2}]},
        pose=_pose("origin of the points"), thickness=_num("line width"),
        scale_invariant={"type": "boolean", "description": "thickness in pixels, not metres"},
        points=_array(_obj("foxglove.Point3", "a point", x=_num("x"), y=_num("y"), z=_num("z")), "points"),
        color=_color("colour"))
    entity = _obj("foxglove.SceneEntity", "a visual element of the 3D scene",
                  timestamp=_time("time of the entity"), frame_id={"type": "string", "description": "frame"},
                  id={"type": "string", "description": "replaces any earlier entity with this id on the topic"},
                  lifetime={"type": "object", "title": "duration", "description": "0: until replaced", "properties": {
                      "sec": {"type": "integer"}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}},
                  frame_locked={"type": "boolean", "description": "follow frame_id as it moves"},
                  cubes=_array(cube, "boxes"), cylinders=_array(cylinder, "cylinders"), lines=_array(line, "lines"))
    deletion = _obj("foxglove.SceneEntityDeletion", "a command to delete entities",
                    timestamp=_time("deletes entities created before this time"),
                    type={"title": "foxglove.SceneEntityDeletionType", "description": "what to delete",
                          "oneOf": [{"title": "MATCHING_ID", "const": 0}, {"title": "ALL", "const": 1}]},
                    id={"type": "string", "description": "the entity to delete (MATCHING_ID)"})
    return _obj("foxglove.SceneUpdate", "an update to the entities of a 3D scene",
                deletions=_array(deletion, "entities to delete"), entities=_array(entity, "entities"))


#: Topic → JSON schema of the Foxglove topics a trial log carries.
SCHEMAS: dict[str, dict[str, Any]] = {
    "/tf": _obj("foxglove.FrameTransform", "the robot's pose as a transform from the lab frame",
                timestamp=_time("time of the pose"),
                parent_frame_id={"type": "string", "description": "parent frame"},
                child_frame_id={"type": "string", "description": "child frame"},
                translation=_vector3("translation"), rotation=_quaternion("rotation")),
    "/robot/pose": _obj("foxglove.PoseInFrame", "the robot's pose in the lab frame",
                        timestamp=_time("time of the pose"), frame_id={"type": "string", "description": "frame"},
                        pose=_pose("pose")),
    "/robot/model": _scene_update(),
    "/scene": _scene_update(),
}


# ----------------------------------------------------------------------------- messages
def stamp(t: float) -> dict[str, int]:
    """Wall-clock seconds as Foxglove's ``{sec, nsec}``."""
    ns = round(t * 1e9)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _v(x: float, y: float, z: float) -> dict[str, float]:
    return {"x": float(x), "y": float(y), "z": float(z)}


def _q(x: float, y: float, z: float, w: float) -> dict[str, float]:
    return {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}


IDENTITY = {"position": _v(0, 0, 0), "orientation": _q(0, 0, 0, 1)}


def _rgba(r: float, g: float, b: float, a: float = 1.0) -> dict[str, float]:
    return {"r": r, "g": g, "b": b, "a": a}


def pose_messages(t: float, position: list[float], quaternion: list[float]) -> dict[str, dict[str, Any]]:
    """``/tf`` and ``/robot/pose`` for one mocap pose (lab-frame position, quaternion x, y, z, w)."""
    ts = stamp(t)
    return {"/tf": {"timestamp": ts, "parent_frame_id": LAB, "child_frame_id": ROBOT,
                    "translation": _v(*position), "rotation": _q(*quaternion)},
            "/robot/pose": {"timestamp": ts, "frame_id": LAB,
                            "pose": {"position": _v(*position), "orientation": _q(*quaternion)}}}


def _entity(t: float, frame: str, name: str, **primitives: list[dict[str, Any]]) -> dict[str, Any]:
    return {"timestamp": stamp(t), "frame_id": frame, "id": name, "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": frame == ROBOT, **primitives}


def robot_model(t: float, design: tuple[float, float, float, float]) -> dict[str, Any]:
    """``/robot/model``: the body box and its two legs, in the robot frame (x along the leg axis)."""
    x, y, z, leg = design
    plate = 0.006  # leg thickness drawn, m
    legs = [{"pose": {"position": _v(side * (x / 2 + plate), 0.0, -leg / 2), "orientation": _q(0, 0, 0, 1)},
             "size": _v(plate, 0.03, leg), "color": _rgba(0.9, 0.5, 0.1)} for side in (-1, 1)]
    body = {"pose": IDENTITY, "size": _v(x, y, z), "color": _rgba(0.2, 0.4, 0.8, 0.9)}
    return {"deletions": [], "entities": [_entity(t, ROBOT, "robot", cubes=[body, *legs])]}


def scene(t: float, setpoint: tuple[float, float], radius: float | None, start: tuple[float, float] | None
          ) -> dict[str, Any]:
    """``/scene``: the setpoint, the start circle and this trial's start point, in the lab frame."""
    disc = {"pose": {"position": _v(setpoint[0], setpoint[1], 0.001), "orientation": _q(0, 0, 0, 1)},
            "size": _v(0.1, 0.1, 0.002), "bottom_scale": 1.0, "top_scale": 1.0, "color": _rgba(0.1, 0.8, 0.2, 0.8)}
    cylinders = [disc]
    lines = []
    if radius is not None:
        points = [_v(setpoint[0] + radius * math.cos(a), setpoint[1] + radius * math.sin(a), 0.001)
                  for a in (2 * math.pi * k / 72 for k in range(72))]
        lines.append({"type": 1, "pose": IDENTITY, "thickness": 2.0, "scale_invariant": True, "points": points,
                      "color": _rgba(0.6, 0.6, 0.6)})
    if start is not None:
        cylinders.append({"pose": {"position": _v(start[0], start[1], 0.001), "orientation": _q(0, 0, 0, 1)},
                          "size": _v(0.05, 0.05, 0.002), "bottom_scale": 1.0, "top_scale": 1.0,
                          "color": _rgba(0.9, 0.2, 0.2, 0.8)})
    return {"deletions": [], "entities": [_entity(t, LAB, "setpoint", cylinders=cylinders, lines=lines)]}
