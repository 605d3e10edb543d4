"""``trial run --foxglove``: a Foxglove viewer sees, live, what the trial log records."""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from websockets.sync.client import ClientConnection, connect

from tumblebot.errors import TumblebotError
from tumblebot.host.live import LATCHED, LiveView, parse_listen
from tumblebot.host.triallog import TrialLogWriter

DESIGN = (0.292, 0.129, 0.098, 0.136)
METADATA = {"trial": "0", "design": json.dumps(DESIGN), "setpoint": json.dumps([1.0, 2.0]),
            "start": json.dumps([1.8, 2.0]), "radius": "0.8"}
POSES = 4
WAIT = 30.0  #: s: generous, a loaded machine still delivers loopback frames far sooner


@contextmanager
def _viewer(live: LiveView) -> Iterator[tuple[ClientConnection, dict[str, Any], dict[int, dict[str, Any]]]]:
    """Connect as Foxglove does and subscribe to every channel, the latched ones last (so
    their resent messages arrive once every other subscription is in place): (connection,
    server info, channels by subscription id)."""
    with connect(live.url, subprotocols=["foxglove.sdk.v1"], open_timeout=WAIT) as ws:  # type: ignore[list-item]
        info = json.loads(ws.recv(timeout=WAIT))
        assert info["op"] == "serverInfo", info
        advertised = json.loads(ws.recv(timeout=WAIT))
        assert advertised["op"] == "advertise", advertised
        ordered = sorted(advertised["channels"], key=lambda c: c["topic"] in LATCHED)
        channels = {k: channel for k, channel in enumerate(ordered, start=1)}
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": k, "channelId": c["id"]}
                                                                for k, c in channels.items()]}))
        yield ws, info, channels


def _received(ws: ClientConnection, channels: dict[int, dict[str, Any]], count: int) -> list[tuple[str, int, bytes]]:
    """The next ``count`` message frames as (topic, log time ns, payload); status frames are skipped."""
    out: list[tuple[str, int, bytes]] = []
    while len(out) < count:
        frame = ws.recv(timeout=WAIT)
        if isinstance(frame, bytes) and frame[0] == 0x01:  # opcode 1: message data
            subscription, log_time = struct.unpack_from("<IQ", frame, 1)
            out.append((channels[subscription]["topic"], log_time, frame[13:]))
    return out


def _logged(path: Path) -> tuple[list[tuple[str, int, bytes]], dict[str, str]]:
    with path.open("rb") as fh:
        rows = [(c.topic, m.log_time, m.data, s.name if s else "")
                for s, c, m in make_reader(fh).iter_messages(log_time_order=False)]
    return [r[:3] for r in rows], {r[0]: r[3] for r in rows}


def test_that_a_late_viewer_sees_the_robot_the_scene_and_every_pose_as_logged(tmp_path: Path) -> None:
    path = tmp_path / "trial.mcap"
    # the scene is written when the log opens, before any viewer looks
    with LiveView("127.0.0.1", 0) as live, TrialLogWriter(path, METADATA, mirror=live.publish) as log, \
            _viewer(live) as (ws, _, channels):
        latched = _received(ws, channels, 2)  # the robot model and the scene, sent again on subscribing
        for i in range(POSES):
            log.write("/pose", {"t": i * 0.1, "p": [1.8 - 0.1 * i, 2.0, 0.07], "q": [0.0, 0.0, 0.0, 1.0], "seq": i},
                      t=1_700_000_000.0 + 0.1 * i)
        log.write("/command", {"right": 2, "left": 0, "kind": "policy"}, t=1_700_000_001.0)
        streamed = _received(ws, channels, 3 * POSES + 1)  # each pose also as /tf and /robot/pose
    logged, schema_names = _logged(path)
    assert sorted(latched) == sorted(m for m in logged if m[0] in LATCHED)
    assert streamed == [m for m in logged if m[0] not in LATCHED]  # same bytes, times, order
    assert {c["topic"]: c["schemaName"] for c in channels.values() if c["topic"] in schema_names} == schema_names
    assert schema_names["/tf"] == "foxglove.FrameTransform" and schema_names["/robot/model"] == "foxglove.SceneUpdate"


def test_that_a_viewer_cannot_publish_call_services_or_set_parameters() -> None:
    with LiveView("127.0.0.1", 0) as live, _viewer(live) as (_, info, _):
        assert info["capabilities"] == []  # no clientPublish, services, parameters: the view is read-only


def test_that_the_live_view_listens_on_loopback_unless_told_otherwise() -> None:
    assert parse_listen("8765") == ("127.0.0.1", 8765)
    assert parse_listen("0.0.0.0:9000") == ("0.0.0.0", 9000)
    for bad in ("web", ":8765", "70000", "-1", "host:"):
        with pytest.raises(TumblebotError, match="expected PORT or HOST:PORT"):
            parse_listen(bad)


def test_that_a_port_in_use_gets_one_clear_error() -> None:
    with LiveView("127.0.0.1", 0) as live, \
            pytest.raises(TumblebotError, match=f"cannot listen on 127.0.0.1:{live.port}"):
        LiveView("127.0.0.1", live.port)
