"""Trial logs carry Foxglove's well-known types, so a trial plays back as a 3D scene."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from tumblebot.host.triallog import TrialLogWriter, read_trial

DESIGN = (0.292, 0.129, 0.098, 0.136)
EXPECTED = {"/tf": "foxglove.FrameTransform", "/robot/pose": "foxglove.PoseInFrame",
            "/robot/model": "foxglove.SceneUpdate", "/scene": "foxglove.SceneUpdate",
            "/pose": "tumblebot.Pose", "/command": "tumblebot.Command"}


def _is(value: Any, kind: str) -> bool:
    if kind in ("number", "integer"):
        return not isinstance(value, bool) and isinstance(value, int if kind == "integer" else int | float)
    return isinstance(value, {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None)}[kind])


def conforms(value: Any, schema: dict[str, Any], where: str = "$") -> list[str]:
    """The JSON-schema subset the logs use: type (or a list of types), properties, items,
    oneOf of consts, minimum/maximum. Properties the schema does not name are errors."""
    errors: list[str] = []
    kinds = schema.get("type")
    if kinds is not None and not any(_is(value, k) for k in ([kinds] if isinstance(kinds, str) else kinds)):
        return [f"{where}: {value!r} is not {kinds}"]
    if ("minimum" in schema and value < schema["minimum"]) or ("maximum" in schema and value > schema["maximum"]):
        errors.append(f"{where}: {value} out of range")
    if "oneOf" in schema and not any(value == option.get("const") for option in schema["oneOf"]):
        errors.append(f"{where}: {value!r} is none of the allowed values")
    if isinstance(value, dict) and schema.get("properties"):
        for key, item in value.items():
            if key not in schema["properties"]:
                errors.append(f"{where}.{key}: not in the schema")
            else:
                errors += conforms(item, schema["properties"][key], f"{where}.{key}")
    if isinstance(value, list) and "items" in schema:
        for i, item in enumerate(value):
            errors += conforms(item, schema["items"], f"{where}[{i}]")
    return errors


def _trial_log(path: Path) -> None:
    metadata = {"trial": "0", "design": json.dumps(DESIGN), "setpoint": json.dumps([1.0, 2.0]),
                "start": json.dumps([1.8, 2.0]), "radius": "0.8"}
    with TrialLogWriter(path, metadata) as log:
        for i in range(5):
            log.write("/pose", {"t": i * 0.1, "p": [1.8 - 0.1 * i, 2.0, 0.07], "q": [0.0, 0.0, 0.0, 1.0],
                                "seq": i}, t=1_700_000_000.0 + 0.1 * i)
        log.write("/command", {"right": 1, "left": -1, "kind": "policy"})


def test_that_a_trial_log_uses_foxglove_schemas_and_every_message_conforms(tmp_path: Path) -> None:
    path = tmp_path / "trial.mcap"
    _trial_log(path)
    seen: dict[str, int] = {}
    with path.open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            assert schema is not None and schema.encoding == "jsonschema" and channel.message_encoding == "json"
            if channel.topic in EXPECTED:
                assert schema.name == EXPECTED[channel.topic], channel.topic
            errors = conforms(json.loads(message.data), json.loads(schema.data))
            assert not errors, (channel.topic, errors[:3])
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
    assert seen["/tf"] == seen["/robot/pose"] == seen["/pose"] == 5
    assert seen["/robot/model"] == seen["/scene"] == 1


def test_that_the_scene_is_the_robot_that_moved_where_mocap_saw_it(tmp_path: Path) -> None:
    path = tmp_path / "trial.mcap"
    _trial_log(path)
    log = read_trial(path)
    for pose, tf, framed in zip(log.topic("/pose"), log.topic("/tf"), log.topic("/robot/pose"), strict=True):
        t = tf.data["translation"]
        assert [t["x"], t["y"], t["z"]] == pose.data["p"]
        assert (tf.data["parent_frame_id"], tf.data["child_frame_id"]) == ("lab", "robot")
        assert framed.data["pose"]["position"] == t and framed.data["frame_id"] == "lab"
        assert tf.data["timestamp"]["sec"] == 1_700_000_000  # wall-clock time, as the log's own
    model = log.topic("/robot/model")[0].data["entities"][0]
    assert model["frame_id"] == "robot" and model["frame_locked"]
    body, *legs = model["cubes"]
    assert (body["size"]["x"], body["size"]["y"], body["size"]["z"]) == DESIGN[:3]
    assert len(legs) == 2 and all(leg["size"]["z"] == DESIGN[3] for leg in legs)
    scene = log.topic("/scene")[0].data["entities"][0]
    setpoint, start = scene["cylinders"]
    assert (setpoint["pose"]["position"]["x"], setpoint["pose"]["position"]["y"]) == (1.0, 2.0)
    assert (start["pose"]["position"]["x"], start["pose"]["position"]["y"]) == (1.8, 2.0)
    circle = scene["lines"][0]["points"]
    assert all(abs(((p["x"] - 1.0) ** 2 + (p["y"] - 2.0) ** 2) ** 0.5 - 0.8) < 1e-9 for p in circle)


def test_that_a_log_without_a_design_has_no_scene_but_still_the_poses(tmp_path: Path) -> None:
    path = tmp_path / "bare.mcap"
    with TrialLogWriter(path, {"trial": "1"}) as log:
        log.write("/pose", {"p": [0.0, 0.0, 0.0], "q": [0.0, 0.0, 0.0, 1.0]})
    got = read_trial(path)
    assert not got.topic("/robot/model") and len(got.topic("/tf")) == 1


def test_that_the_shipped_layout_shows_the_trial_topics() -> None:
    layout = json.loads((Path(__file__).parents[2] / "docs" / "foxglove-layout.json").read_text())
    text = json.dumps(layout)
    for topic in ("/robot/model", "/scene", "/decision"):
        assert topic in text
    assert '"followTf": "robot"' in text


def _foxglove_reads(schema: dict[str, Any], where: str = "$") -> list[str]:
    """What Foxglove's JSON-schema reader (it builds a message definition from the schema,
    field by field) would refuse: a ``type`` that is not one name (``["number", "null"]``
    made it reject ``/pose``), an object without ``properties`` or an array without
    ``items`` (it stopped reading ``/scene`` at ``deletions``), an enum that is not
    ``oneOf`` constants."""
    kind = schema.get("type")
    if kind is None:
        options = schema.get("oneOf")
        if not options or not all("const" in o for o in options):
            return [f"{where}: neither a type nor an enum of constants"]
        return []
    if not isinstance(kind, str):
        return [f"{where}: type {kind!r} is not one name"]
    if kind == "object":
        if not isinstance(schema.get("properties"), dict):
            return [f"{where}: an object without properties"]
        return [e for key, sub in schema["properties"].items() for e in _foxglove_reads(sub, f"{where}.{key}")]
    if kind == "array":
        return _foxglove_reads(schema["items"], f"{where}[]") if "items" in schema else [f"{where}: no items"]
    return [] if kind in ("string", "number", "integer", "boolean") else [f"{where}: unknown type {kind!r}"]


def test_that_every_topic_of_a_trial_log_has_a_schema_foxglove_can_read(tmp_path: Path) -> None:
    path = tmp_path / "trial.mcap"
    _trial_log(path)
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None and len(summary.schemas) >= 9
    for schema in summary.schemas.values():
        assert not _foxglove_reads(json.loads(schema.data)), (schema.name, _foxglove_reads(json.loads(schema.data)))
