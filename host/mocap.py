"""Motion-capture pose sources, chosen by a URL-like string, and the pose filter.

=========================================  ==============================================
``udp://0.0.0.0:47900?body=tumbler``       the UDP pose stream (docs/protocol.md): what the
                                           digital twin publishes, and what a lab can feed
                                           from any other tracker
``motioncapture://vicon@10.0.0.5?body=B``  a real system through the ``motioncapture``
                                           package: vicon, optitrack, qualisys, vrpn, nokov…;
                                           extra query keys go to the library as options
``motioncapture://mock?body=B&rigid_bodies=B(x,y,z,qw,qx,qy,qz)``
                                           that library's own mock source (static bodies)
``replay:///path/trial-0003.mcap``         the poses of a recorded trial, as recorded
``mock://?x=0.4&y=0.2&yaw=0``              a fixed pose at 100 Hz, for dry runs
=========================================  ==============================================

Every :class:`Pose` carries the host's receive time (``time.monotonic()``) and the
source's own timestamp and sequence number when it has them. :class:`PoseFilter` drops
duplicate and out-of-order frames, rejects jumps faster than a maximum speed, and tells
how old the newest accepted pose is; the controller treats an old pose as lost tracking.
Host-side timing never uses the source's clock, so a jump in that clock cannot stall or
rush the controller.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import math
import queue
import select
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import parse_qsl, urlsplit

from tumblebot.errors import TumblebotError
from tumblebot.pi_agent import protocol as P

#: Datagram schema versions of the UDP pose stream: 1 plain JSON, 2 signed (JSON + tag).
POSE_STREAM_VERSION = 1
SIGNED_POSE_VERSION = 2
TAG_HEX = 2 * P.MAC_SIZE  #: the signature's length in hex digits
DEFAULT_POSE_PORT = 47900
MAX_POSE_DATAGRAM = 512


class MocapError(TumblebotError):
    """A pose source that cannot be opened, or a malformed pose."""


@dataclass(frozen=True)
class Pose:
    """A rigid-body pose in the lab frame: metres, quaternion ``(x, y, z, w)``.

    ``t`` is the host's ``time.monotonic()`` when the pose arrived; ``source_time`` (s) and
    ``seq`` are the source's own timestamp and frame counter, when it has them.
    """

    t: float
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    source_time: float | None = None
    seq: int | None = None

    def to_json(self) -> dict[str, Any]:
        """The trial log's ``/pose`` message; ``source_time`` and ``seq`` only when the source has them."""
        out: dict[str, Any] = {"t": self.t, "p": list(self.position), "q": list(self.quaternion)}
        if self.source_time is not None:
            out["source_time"] = self.source_time
        if self.seq is not None:
            out["seq"] = self.seq
        return out


class PoseAuthError(MocapError):
    """A pose datagram that is not signed with the stream's key (or is a replay)."""


def parse_pose_datagram(data: bytes, body: str | None, received: float, key: bytes | None = None) -> Pose:
    """Decode one UDP pose-stream datagram (see docs/protocol.md); raises MocapError.
    With ``key`` (the stream's :func:`~tumblebot.pi_agent.protocol.pose_key`), only a
    signed datagram (version 2, with ``seq``) whose signature verifies is accepted, checked
    in constant time before its JSON is read."""
    if len(data) > MAX_POSE_DATAGRAM:
        raise MocapError(f"pose datagram of {len(data)} bytes (max {MAX_POSE_DATAGRAM})")
    version = POSE_STREAM_VERSION
    if key is not None:
        data, tag = data[:-TAG_HEX], data[-TAG_HEX:]
        if len(tag) != TAG_HEX or not hmac.compare_digest(P.pose_tag(key, data).encode(), tag):
            raise PoseAuthError("pose datagram not signed with this stream's key")
        version = SIGNED_POSE_VERSION
    try:
        msg = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise MocapError("pose datagram is not JSON") from None
    if not isinstance(msg, dict) or msg.get("v") != version:
        raise MocapError(f"pose datagram version {msg.get('v') if isinstance(msg, dict) else None!r} "
                         f"is not {version}")
    if key is not None and msg.get("seq") is None:
        raise MocapError("a signed pose datagram needs seq")
    if body is not None and msg.get("body") != body:
        raise MocapError(f"pose of body {msg.get('body')!r}, not {body!r}")
    p, q, t, seq = msg.get("p"), msg.get("q"), msg.get("t"), msg.get("seq")
    if not (isinstance(p, list) and len(p) == 3 and isinstance(q, list) and len(q) == 4):
        raise MocapError("pose datagram needs p: [x, y, z] and q: [qx, qy, qz, qw]")
    values = [*p, *q]
    if not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in values):
        raise MocapError("pose datagram has a non-finite or non-numeric value")
    norm = math.sqrt(sum(float(v) ** 2 for v in q))
    if not 0.9 < norm < 1.1:
        raise MocapError(f"pose quaternion has norm {norm:.3f}, not 1")
    if not isinstance(t, int | float) or isinstance(t, bool) or not math.isfinite(t):
        raise MocapError("pose datagram needs a finite timestamp t (s)")
    if seq is not None and (not isinstance(seq, int) or isinstance(seq, bool) or seq < 0):
        raise MocapError("pose datagram seq must be a non-negative integer")
    qn = tuple(float(v) / norm for v in q)
    return Pose(received, (float(p[0]), float(p[1]), float(p[2])), (qn[0], qn[1], qn[2], qn[3]), float(t), seq)


def encode_pose_datagram(body: str, seq: int, t: float, position: Any, quaternion: Any,
                         key: bytes | None = None) -> bytes:
    """One UDP pose-stream datagram (what the twin sends; a lab bridge writes the same).
    With ``key`` (the shared 32-byte key, as the agent's) it is signed: version 2, the JSON
    followed by 32 hex digits of HMAC-SHA256 under :func:`~tumblebot.pi_agent.protocol.pose_key`.
    ``seq`` must then never go back, across restarts of the sender too."""
    text = json.dumps({"v": SIGNED_POSE_VERSION if key is not None else POSE_STREAM_VERSION, "body": body,
                       "seq": seq, "t": round(float(t), 6), "p": [round(float(v), 6) for v in position],
                       "q": [round(float(v), 7) for v in quaternion]}, separators=(",", ":")).encode()
    return text if key is None else text + P.pose_tag(P.pose_key(key), text).encode()


class PoseSource(Protocol):
    url: str

    def poll(self, timeout: float) -> list[Pose]:
        """Poses that arrived, waiting at most ``timeout`` s for the first one."""

    def close(self) -> None: ...


class UdpPoseSource:
    """The UDP pose stream; with ``key`` only signed datagrams whose ``seq`` is above every
    one accepted before (so no captured pose is replayed as a fresher one)."""

    def __init__(self, url: str, host: str, port: int, body: str | None, key: bytes | None = None) -> None:
        self.url, self.body = url, body
        self.key = None if key is None else P.pose_key(key)
        self.last_seq: int | None = None
        self.unauthenticated = 0  #: datagrams whose signature did not verify
        self.replayed = 0  #: signed datagrams whose seq was not above the last accepted
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise MocapError(f"{url}: cannot listen on {host}:{port}: {exc.strerror}") from None
        self.sock.setblocking(False)
        self.malformed = 0
        self.last_error = ""

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()
        return host, port

    def poll(self, timeout: float) -> list[Pose]:
        readable, _, _ = select.select([self.sock], [], [], max(0.0, timeout))
        out: list[Pose] = []
        if not readable:
            return out
        for _ in range(256):
            try:
                data = self.sock.recv(MAX_POSE_DATAGRAM + 1)
            except BlockingIOError:
                break
            try:
                pose = parse_pose_datagram(data, self.body, time.monotonic(), self.key)
            except PoseAuthError as exc:
                self.unauthenticated += 1
                self.last_error = str(exc)
                continue
            except MocapError as exc:
                self.malformed += 1
                self.last_error = str(exc)
                continue
            if self.key is not None:
                assert pose.seq is not None
                if self.last_seq is not None and pose.seq <= self.last_seq:
                    self.replayed += 1
                    continue
                self.last_seq = pose.seq
            out.append(pose)
        return out

    def close(self) -> None:
        self.sock.close()


class ThreadedSource:
    """Runs a blocking ``next_pose()`` in a thread and hands poses over through a queue."""

    def __init__(self, url: str) -> None:
        self.url = url
        self._queue: queue.Queue[Pose] = queue.Queue(maxsize=10_000)
        self._stop = threading.Event()
        self.error: Exception | None = None
        self._thread = threading.Thread(target=self._loop, daemon=True, name=f"mocap {url}")

    def start(self) -> None:
        self._thread.start()

    def next_pose(self) -> Pose | None:
        raise NotImplementedError

    def _loop(self) -> None:
        try:
            while not self._stop.is_set():
                pose = self.next_pose()
                if pose is not None:
                    self._queue.put(pose)
        except Exception as exc:  # surfaced by poll(): the source died
            self.error = exc

    def poll(self, timeout: float) -> list[Pose]:
        out: list[Pose] = []
        try:
            out.append(self._queue.get(timeout=max(0.0, timeout)))
        except queue.Empty:
            if self.error is not None:
                raise MocapError(f"{self.url}: {self.error}") from None
            return out
        while True:
            try:
                out.append(self._queue.get_nowait())
            except queue.Empty:
                return out

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


class MotionCaptureSource(ThreadedSource):
    """A system the ``motioncapture`` package supports, one rigid body of it."""

    def __init__(self, url: str, system: str, options: dict[str, str], body: str) -> None:
        super().__init__(url)
        try:
            import motioncapture
        except ImportError:
            raise MocapError("the motioncapture package is not installed (pip install 'tumblebot[host]')") from None
        try:
            self.mc = motioncapture.connect(system, options)
        except RuntimeError as exc:
            raise MocapError(f"{url}: {exc}") from None
        self.body, self.seq = body, 0
        self.start()

    def next_pose(self) -> Pose | None:
        self.mc.waitForNextFrame()
        now = time.monotonic()
        bodies = self.mc.rigidBodies
        if self.body not in bodies:
            return None  # not tracked in this frame: counts as lost if it lasts
        rb = bodies[self.body]
        p, q = rb.position, rb.rotation
        values = [float(p[0]), float(p[1]), float(p[2]), float(q.x), float(q.y), float(q.z), float(q.w)]
        if not all(math.isfinite(v) for v in values):
            return None
        self.seq += 1
        return Pose(now, (values[0], values[1], values[2]), (values[3], values[4], values[5], values[6]), None,
                    self.seq)


class MockSource(ThreadedSource):
    """A fixed pose at ``rate`` Hz: for dry runs of the controller and the trial CLI."""

    def __init__(self, url: str, x: float, y: float, z: float, yaw: float, rate: float) -> None:
        super().__init__(url)
        self.pose = ((x, y, z), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))
        self.period, self.seq = 1.0 / rate, 0
        self.start()

    def next_pose(self) -> Pose | None:
        time.sleep(self.period)
        self.seq += 1
        return Pose(time.monotonic(), self.pose[0], self.pose[1], time.time(), self.seq)


class ReplaySource(ThreadedSource):
    """The poses of a recorded trial (its MCAP log), at the pace they were recorded.

    A log starts when its trial started, after the host had seen the robot sit at the start
    point. So the replay first holds the recording's first pose (the robot waiting at the
    start, 100 Hz, fresh times) until :meth:`trial_starts`, which the trial set calls as its
    trial begins; only then does the recording play, at its pace, so the host's steps see the
    poses they saw when it was recorded. After the last recorded pose the robot stays where
    it ended for ``HOLD_AFTER`` s, then the source falls silent (tracking lost)."""

    HOLD_PERIOD = 0.01  #: s between held poses (the start, and the end)
    HOLD_AFTER = 2.0  #: s the last pose is held after the recording ends

    def __init__(self, url: str, path: Path, speed: float) -> None:
        super().__init__(url)
        from tumblebot.host.triallog import read_trial

        try:
            log = read_trial(path)
        except OSError as exc:
            raise MocapError(f"{url}: cannot read {path}: {exc.strerror}") from None
        self.poses = [m for m in log.messages if m.topic == "/pose"]
        if not self.poses:
            raise MocapError(f"{url}: {path} holds no poses")
        self.speed, self.index, self.seq = speed, 0, 0
        self._playing = threading.Event()
        self.start_wall = 0.0
        self.start_log = self.poses[0].log_time
        self.ended: float | None = None
        self.start()

    def trial_starts(self) -> None:
        """The trial begins: play the recording from its first pose, from now."""
        if not self._playing.is_set():
            self.start_wall = time.monotonic()
            self._playing.set()

    def _held(self, message: Any) -> Pose:
        time.sleep(self.HOLD_PERIOD)
        self.seq += 1
        d = message.data
        p, q = d["p"], d["q"]
        return Pose(time.monotonic(), (p[0], p[1], p[2]), (q[0], q[1], q[2], q[3]), None, self.seq)

    def next_pose(self) -> Pose | None:
        if not self._playing.is_set():
            return self._held(self.poses[0])  # the robot at the start, waiting for the trial
        if self.index >= len(self.poses):
            if self.ended is None:
                self.ended = time.monotonic()
            if time.monotonic() - self.ended < self.HOLD_AFTER:
                return self._held(self.poses[-1])
            time.sleep(0.05)
            return None  # the recording is over: the pose goes stale, like lost tracking
        m = self.poses[self.index]
        due = self.start_wall + (m.log_time - self.start_log) / self.speed
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        self.index += 1
        self.seq += 1
        d = m.data
        p, q = d["p"], d["q"]
        return Pose(time.monotonic(), (p[0], p[1], p[2]), (q[0], q[1], q[2], q[3]), d.get("source_time"), self.seq)


def _float(query: dict[str, str], key: str, default: float, url: str) -> float:
    raw = query.pop(key, None)
    if raw is None:
        return default
    try:
        value = float(raw)
    except ValueError:
        raise MocapError(f"{url}: {key}={raw!r} is not a number") from None
    if not math.isfinite(value):
        raise MocapError(f"{url}: {key}={raw!r} is not finite")
    return value


def _pose_stream_key(url: str, host: str, query: dict[str, str]) -> bytes | None:
    """``key=PATH`` (the shared key file, checked as the agent's); without one, a source that
    listens beyond loopback is refused unless ``insecure=1``: anyone on the network could
    then steer the robot with forged poses."""
    insecure = query.get("insecure", "0")
    if insecure not in ("0", "1"):
        raise MocapError(f"{url}: insecure must be 0 or 1")
    if "key" in query:
        try:
            return P.read_key_file(query["key"])
        except P.KeyFileError as exc:
            raise MocapError(f"{url}: {exc}") from None
    try:
        loopback = ipaddress.ip_address(socket.gethostbyname(host)).is_loopback
    except (OSError, ValueError):
        raise MocapError(f"{url}: cannot resolve {host!r}") from None
    if not loopback and insecure != "1":
        raise MocapError(f"{url}: an unsigned pose stream listening on {host} lets anyone on the network forge "
                         "the robot's pose; add key=PATH (the shared key; the sender signs with it), or "
                         "insecure=1 on a network you trust")
    return None


def open_source(url: str) -> PoseSource:
    """Open the pose source ``url`` (see the module docs for the forms)."""
    parts = urlsplit(url)
    query = dict(parse_qsl(parts.query, keep_blank_values=True))
    scheme = parts.scheme
    if scheme == "udp":
        host = parts.hostname or "0.0.0.0"
        try:
            port = parts.port or DEFAULT_POSE_PORT
        except ValueError:
            raise MocapError(f"{url}: the port is not a number") from None
        key = _pose_stream_key(url, host, query)
        return UdpPoseSource(url, host, port, query.get("body"), key)
    if scheme == "motioncapture":
        system = parts.username or parts.hostname or ""
        if not system:
            raise MocapError(f"{url}: name the system, e.g. motioncapture://vicon@10.0.0.5?body=tumbler")
        body = query.pop("body", None)
        if not body:
            raise MocapError(f"{url}: which rigid body? add ?body=NAME")
        options = dict(query)
        if parts.username and parts.hostname:
            options.setdefault("hostname", parts.hostname)
        return MotionCaptureSource(url, system, options, body)
    if scheme == "replay":
        path = Path(parts.path)
        if not path.is_file():
            raise MocapError(f"{url}: {path} does not exist")
        speed = _float(query, "speed", 1.0, url)
        if speed <= 0:
            raise MocapError(f"{url}: speed must be positive")
        return ReplaySource(url, path, speed)
    if scheme == "mock":
        rate = _float(query, "rate", 100.0, url)
        if not 1.0 <= rate <= 1000.0:
            raise MocapError(f"{url}: rate must be 1–1000 Hz")
        return MockSource(url, _float(query, "x", 0.0, url), _float(query, "y", 0.0, url),
                          _float(query, "z", 0.05, url), _float(query, "yaw", 0.0, url), rate)
    raise MocapError(f"mocap source {url!r}: unknown scheme {scheme!r}; use udp://, motioncapture://, replay:// "
                     "or mock://")


class PoseFilter:
    """Accepts poses in order, rejects outliers, and says when tracking is lost.

    Args:
        max_speed: m/s; a pose that would mean a faster jump from the last accepted one is
            an outlier. After ``reanchor_after`` outliers in a row the new position is
            accepted (the robot really was moved, or the last accepted pose was the bad one).
        lost_after: s; with no accepted pose for this long, tracking is lost.
    """

    def __init__(self, max_speed: float = 3.0, lost_after: float = 0.5, reanchor_after: int = 20) -> None:
        if not max_speed > 0 or not lost_after > 0:
            raise MocapError("max_speed and lost_after must be positive")
        self.max_speed, self.lost_after, self.reanchor_after = max_speed, lost_after, reanchor_after
        self.last: Pose | None = None
        self.rejected: dict[str, int] = {"duplicate": 0, "out_of_order": 0, "outlier": 0}
        self.clock_resets = 0
        self._outliers_in_row = 0

    def offer(self, pose: Pose) -> bool:
        """Whether ``pose`` is accepted as the newest pose."""
        last = self.last
        if last is not None:
            if pose.seq is not None and last.seq is not None:
                if pose.seq == last.seq:
                    self.rejected["duplicate"] += 1
                    return False
                if pose.seq < last.seq and last.seq - pose.seq < 1000:
                    self.rejected["out_of_order"] += 1
                    return False
            if pose.source_time is not None and last.source_time is not None:
                back = last.source_time - pose.source_time
                if back >= 0 and pose.seq is None:
                    self.rejected["duplicate" if back == 0 else "out_of_order"] += 1
                    return False
                if back > 1.0:
                    self.clock_resets += 1  # the source's clock jumped back: trust the host's order
            dt = pose.t - last.t
            if pose.source_time is not None and last.source_time is not None \
                    and 0 < pose.source_time - last.source_time < 1.0:
                dt = pose.source_time - last.source_time
            jump = math.dist(pose.position[:2], last.position[:2])
            if jump > self.max_speed * max(dt, 0.01) and self._outliers_in_row < self.reanchor_after:
                self._outliers_in_row += 1
                self.rejected["outlier"] += 1
                return False
        self._outliers_in_row = 0
        self.last = pose
        return True

    def age(self, now: float) -> float:
        """Seconds since the newest accepted pose arrived (inf before any)."""
        return math.inf if self.last is None else now - self.last.t

    def lost(self, now: float) -> bool:
        return self.age(now) > self.lost_after
