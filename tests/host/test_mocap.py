"""Pose sources and the pose filter."""

from __future__ import annotations

import itertools
import json
import math
import socket
import time
from pathlib import Path
from typing import Any

import pytest

from tumblebot.host.mocap import (
    MocapError,
    Pose,
    PoseFilter,
    encode_pose_datagram,
    open_source,
    parse_pose_datagram,
)
from tumblebot.host.triallog import TrialLogWriter


def test_that_a_pose_datagram_round_trips() -> None:
    wire = encode_pose_datagram("tumbler", 7, 12.5, (1.0, -2.0, 0.05), (0.0, 0.0, 0.6, 0.8))
    pose = parse_pose_datagram(wire, "tumbler", received=3.0)
    assert pose.position == (1.0, -2.0, 0.05) and pose.quaternion == pytest.approx((0, 0, 0.6, 0.8))
    assert (pose.t, pose.source_time, pose.seq) == (3.0, 12.5, 7)


@pytest.mark.parametrize(("payload", "message"), [
    (b"\xff\xfe", "not JSON"),
    (b"[1, 2]", "version"),
    (json.dumps({"v": 2, "p": [0, 0, 0], "q": [0, 0, 0, 1], "t": 0}).encode(), "version"),
    (json.dumps({"v": 1, "body": "other", "p": [0, 0, 0], "q": [0, 0, 0, 1], "t": 0}).encode(), "not 'tumbler'"),
    (json.dumps({"v": 1, "body": "tumbler", "p": [0, 0], "q": [0, 0, 0, 1], "t": 0}).encode(), "needs p"),
    (b'{"v": 1, "body": "tumbler", "p": [NaN, 0, 0], "q": [0, 0, 0, 1], "t": 0}', "non-finite"),
    (json.dumps({"v": 1, "body": "tumbler", "p": [0, 0, 0], "q": [0, 0, 0, 3], "t": 0}).encode(), "norm"),
    (json.dumps({"v": 1, "body": "tumbler", "p": [0, 0, 0], "q": [0, 0, 0, 1]}).encode(), "timestamp"),
    (json.dumps({"v": 1, "body": "tumbler", "p": [0, 0, 0], "q": [0, 0, 0, 1], "t": 0, "seq": -1}).encode(), "seq"),
    (b" " * 600, "bytes"),
])
def test_that_malformed_pose_datagrams_are_refused(payload: bytes, message: str) -> None:
    with pytest.raises(MocapError, match=message):
        parse_pose_datagram(payload, "tumbler", received=0.0)


def test_that_the_udp_source_receives_poses_and_counts_bad_ones() -> None:
    src = open_source("udp://127.0.0.1:0?body=tumbler")
    try:
        addr = src.address  # type: ignore[attr-defined]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(encode_pose_datagram("tumbler", 1, 0.0, (0.1, 0.2, 0.05), (0, 0, 0, 1)), addr)
            s.sendto(b"garbage", addr)
            s.sendto(encode_pose_datagram("tumbler", 2, 0.01, (0.1, 0.2, 0.05), (0, 0, 0, 1)), addr)
        poses: list[Pose] = []
        deadline = time.monotonic() + 2
        while len(poses) < 2 and time.monotonic() < deadline:
            poses += src.poll(0.1)
        assert [p.seq for p in poses] == [1, 2]
        assert src.malformed == 1  # type: ignore[attr-defined]
    finally:
        src.close()


def test_that_the_motioncapture_adapter_reads_the_librarys_own_mock_source() -> None:
    # motioncapture's mock takes bodies as name(x,y,z,qw,qx,qy,qz); we hand out (x, y, z, w).
    src = open_source("motioncapture://mock?body=tumbler&rigid_bodies=tumbler(1,2,0.1,0.5,0.5,0.5,0.5);"
                      "other(0,0,0,1,0,0,0)")
    try:
        poses: list[Pose] = []
        deadline = time.monotonic() + 3
        while len(poses) < 5 and time.monotonic() < deadline:
            poses += src.poll(0.2)
        assert len(poses) >= 5
        assert poses[0].position == pytest.approx((1.0, 2.0, 0.1))
        assert poses[0].quaternion == pytest.approx((0.5, 0.5, 0.5, 0.5))
        assert [p.seq for p in poses] == sorted(p.seq or 0 for p in poses)
        assert all(p.seq is not None for p in poses)
        assert all(b.t > a.t for a, b in itertools.pairwise(poses))
    finally:
        src.close()


def test_that_a_body_the_mocap_system_does_not_track_yields_no_pose() -> None:
    src = open_source("motioncapture://mock?body=tumbler&rigid_bodies=other(0,0,0,1,0,0,0)")
    try:
        assert src.poll(0.3) == []
    finally:
        src.close()


@pytest.mark.parametrize(("url", "message"), [
    ("ftp://x", "unknown scheme"),
    ("motioncapture://mock", "which rigid body"),
    ("motioncapture://nosuchsystem?body=b", "Unknown motion capture type"),
    ("replay:///no/such/file.mcap", "does not exist"),
    ("mock://?x=abc", "not a number"),
    ("mock://?rate=0", "rate"),
    ("udp://127.0.0.1:notaport", "port"),
])
def test_that_bad_source_urls_get_a_clear_error(url: str, message: str) -> None:
    with pytest.raises(MocapError, match=message):
        open_source(url)


def test_that_the_mock_and_replay_sources_produce_poses(tmp_path: Path) -> None:
    src = open_source("mock://?x=0.4&y=-0.2&yaw=1.0&rate=200")
    try:
        poses = src.poll(0.5)
        assert poses and poses[0].position[:2] == (0.4, -0.2)
        assert 2 * math.atan2(poses[0].quaternion[2], poses[0].quaternion[3]) == pytest.approx(1.0)
    finally:
        src.close()
    log = tmp_path / "trial.mcap"
    with TrialLogWriter(log) as w:
        for i in range(10):
            w.write("/pose", {"t": i * 0.01, "p": [i * 0.01, 0, 0.05], "q": [0, 0, 0, 1], "seq": i},
                    t=1000.0 + i * 0.01)
    src = open_source(f"replay://{log}?speed=2")
    try:
        waiting = src.poll(0.5)  # before the trial starts: the robot held at the recording's start
        assert waiting and all(p.position[0] == 0.0 for p in waiting)
        src.trial_starts()  # type: ignore[attr-defined]
        got: list[Pose] = []
        deadline = time.monotonic() + 3
        while time.monotonic() < deadline and not (got and got[-1].position[0] == pytest.approx(0.09)):
            got += src.poll(0.1)
        played = [p.position[0] for p in got]
        start = max(i for i, x in enumerate(played) if x == 0.0)  # held start poses queued before, then the recording
        assert played[start:start + 10] == pytest.approx([i * 0.01 for i in range(10)])
        assert all(b.t >= a.t for a, b in itertools.pairwise(got))
    finally:
        src.close()


def pose(t: float, x: float, seq: int | None = None, source_time: float | None = None) -> Pose:
    return Pose(t, (x, 0.0, 0.05), (0.0, 0.0, 0.0, 1.0), source_time, seq)


def test_that_duplicate_and_out_of_order_frames_are_dropped() -> None:
    f = PoseFilter()
    assert f.offer(pose(0.00, 0.0, seq=1, source_time=10.00))
    assert not f.offer(pose(0.01, 0.0, seq=1, source_time=10.00))  # duplicate
    assert f.offer(pose(0.02, 0.01, seq=3, source_time=10.02))
    assert not f.offer(pose(0.03, 0.0, seq=2, source_time=10.01))  # late
    assert f.rejected["duplicate"] == 1 and f.rejected["out_of_order"] == 1
    g = PoseFilter()  # a source without sequence numbers: its timestamps order the frames
    assert g.offer(pose(0.0, 0.0, source_time=5.0))
    assert not g.offer(pose(0.01, 0.0, source_time=5.0))
    assert not g.offer(pose(0.02, 0.0, source_time=4.99))


def test_that_outliers_are_rejected_until_the_robot_really_is_elsewhere() -> None:
    f = PoseFilter(max_speed=3.0, reanchor_after=5)
    assert f.offer(pose(0.00, 0.0, seq=1, source_time=0.00))
    assert not f.offer(pose(0.01, 1.0, seq=2, source_time=0.01))  # 100 m/s: a glitch
    assert f.offer(pose(0.02, 0.01, seq=3, source_time=0.02))
    for i in range(5):  # the robot was picked up and moved: after a few frames, believe it
        assert not f.offer(pose(0.03 + i * 0.01, 1.5, seq=4 + i, source_time=0.03 + i * 0.01))
    assert f.offer(pose(0.09, 1.5, seq=9, source_time=0.09))


def test_that_source_clock_jumps_do_not_stall_the_filter() -> None:
    f = PoseFilter()
    assert f.offer(pose(0.00, 0.00, seq=1, source_time=100.0))
    assert f.offer(pose(0.01, 0.01, seq=2, source_time=3700.0))  # clock jumped an hour ahead
    assert f.offer(pose(0.02, 0.02, seq=3, source_time=5.0))  # and back (NTP, a restarted PC)
    assert f.clock_resets == 1
    assert f.offer(pose(0.03, 0.03, seq=4, source_time=5.01))
    assert not f.lost(0.03 + 0.4) and f.lost(0.03 + 0.6)  # host time alone decides staleness


def _send_all(addr: tuple[str, int], datagrams: list[bytes]) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for data in datagrams:
            s.sendto(data, addr)


def test_that_forged_replayed_or_altered_poses_never_reach_the_controller(tmp_path: Path) -> None:
    """A sender without the key injects poses ahead of the genuine stream (walking away,
    under the outlier limit), replays captured ones and alters a signed one: only the
    genuine, signed, ever-newer poses come out of the source."""
    import os

    from tumblebot.host.link import new_key

    key_file = tmp_path / "lab.key"
    new_key(key_file)
    key = key_file.read_bytes()
    src = open_source(f"udp://127.0.0.1:0?body=tumbler&key={key_file}")
    try:
        addr = src.address  # type: ignore[attr-defined]
        genuine = [encode_pose_datagram("tumbler", 1000 + k, 0.01 * k, (0.1, 0.2, 0.05), (0, 0, 0, 1), key=key)
                   for k in range(5)]
        forged = [encode_pose_datagram("tumbler", 2000 + k, 0.01 * k, (0.1 + 0.02 * k, 0.2, 0.05), (0, 0, 0, 1))
                  for k in range(5)]  # unsigned, seq ahead
        wrong_key = [encode_pose_datagram("tumbler", 3000, 0.1, (5.0, 0.2, 0.05), (0, 0, 0, 1), key=os.urandom(32))]
        altered = bytearray(genuine[4])
        altered[altered.index(b'"p":[0.1') + 5] = ord("9")  # 0.1 → 0.9 with the signature kept
        _send_all(addr, [genuine[0], genuine[1], *forged, *wrong_key, bytes(altered), genuine[0], genuine[2],
                         genuine[1], genuine[3]])
        deadline = time.monotonic() + 5
        poses: list[Any] = []
        while len(poses) < 4 and time.monotonic() < deadline:
            poses += src.poll(0.2)
        time.sleep(0.2)
        poses += src.poll(0.2)
        assert [p.seq for p in poses] == [1000, 1001, 1002, 1003]
        assert all(p.position[0] == 0.1 for p in poses)
        assert src.unauthenticated == 5 + 1 + 1  # type: ignore[attr-defined]
        assert src.replayed == 2  # type: ignore[attr-defined]
    finally:
        src.close()


def test_that_an_unsigned_pose_stream_off_loopback_is_refused_unless_insecure(tmp_path: Path) -> None:
    with pytest.raises(MocapError, match="lets anyone on the network forge the robot's pose; add key=PATH"):
        open_source("udp://0.0.0.0:0?body=tumbler")
    src = open_source("udp://0.0.0.0:0?body=tumbler&insecure=1")
    src.close()
    loose = tmp_path / "loose.key"
    loose.write_bytes(bytes(range(32)))
    loose.chmod(0o644)
    with pytest.raises(MocapError, match="accessible by group or others"):
        open_source(f"udp://0.0.0.0:0?body=tumbler&key={loose}")
    with pytest.raises(MocapError, match="insecure must be 0 or 1"):
        open_source("udp://127.0.0.1:0?body=tumbler&insecure=yes")
