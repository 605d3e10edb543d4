"""The host's end of the UDP link to the Pi agent (docs/protocol.md, "UDP link").

HELLO out and SESSION back (the agent's session id, from which the keys of both
directions derive), then authenticated COMMAND and STOP datagrams out, TELEMETRY_REQUEST
out and TELEMETRY back. The epoch is the host's wall-clock second at start and the
counter starts at the nanosecond within that second, then rises by one per datagram. The
agent accepts a restarted host (a later second, or later in the same second than any
datagram the old one could have sent) and refuses replays. When the agent stops answering
(it restarted, and has a new session id), :meth:`AgentClient.request_telemetry` says
HELLO again; nothing is sent under a session the agent has not confirmed.
"""

from __future__ import annotations

import collections
import json
import os
import random
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tumblebot.errors import TumblebotError
from tumblebot.pi_agent import protocol as P


class LinkError(TumblebotError):
    """The agent address or key is unusable."""


def load_host_key(path: Path) -> bytes:
    """The shared 32-byte key, under the agent's rule (:func:`protocol.read_key_file`)."""
    try:
        return P.read_key_file(path)
    except P.KeyFileError as exc:
        raise LinkError(str(exc)) from None


def parse_address(text: str, default_port: int = P.DEFAULT_PORT) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = text, str(default_port)
    try:
        number = int(port)
    except ValueError:
        raise LinkError(f"address {text!r}: port {port!r} is not a number") from None
    if not 0 < number < 65536 or not host:
        raise LinkError(f"address {text!r} must be HOST:PORT")
    try:
        resolved = socket.gethostbyname(host)
    except OSError:
        raise LinkError(f"address {text!r}: cannot resolve {host!r}") from None
    return resolved, number


class AgentClient:
    """Sends commands to one agent and tracks whether it answers.

    Commands go out only once the agent has told its session id (``session``): until
    then :meth:`command` and :meth:`stop` send a HELLO instead (counted in ``unsent``),
    which is what a robot with no host would do anyway: nothing.
    """

    HELLO_INTERVAL = 0.2  #: s between HELLOs while there is no answer
    #: s of its own silence after which the host takes its session as expired (the agent
    #: expires it after 1 s without a valid datagram) and says HELLO before anything else
    SESSION_IDLE = 0.8
    RESYNC_AFTER = 1.0  #: s without telemetry (while asking for it) before saying HELLO again

    def __init__(self, address: tuple[str, int], key: bytes, sender: int | None = None) -> None:
        # A random sender id per host process: two hosts on one key never share replay state.
        self.address, self.key = address, key
        self.sender = sender if sender is not None else random.randrange(2, 2**32)
        now = time.time_ns()
        self.epoch = now // 1_000_000_000
        # A host restarted within the same second starts above anything the old one sent
        # (it cannot have sent more than one datagram per nanosecond).
        self.counter = now % 1_000_000_000
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("0.0.0.0", 0))
        self.sock.setblocking(False)
        self.keys: P.LinkKeys | None = None  #: keys of the agent's confirmed session
        self._hello_keys = P.LinkKeys.derive(key, bytes(P.SESSION_SIZE))  # only .hello is used before a session
        self._hello_nonce: int | None = None
        self.last_hello_at = -1e9
        self.last_telemetry_at = -1e9  #: monotonic time of the last authenticated TELEMETRY
        self.last_telemetry: dict[str, Any] = {}
        self.last_request_at = -1e9
        self.last_sent_at = -1e9  #: monotonic time of the last session datagram sent
        self._nonces: collections.deque[int] = collections.deque(maxlen=8)  #: the latest telemetry requests'
        self._last_telemetry_counter: tuple[int, int] | None = None
        self.send_errors = 0
        self.unsent = 0
        self.sessions = 0  #: sessions adopted (more than one: the agent restarted)
        self.foreign_telemetry = 0  #: authentic telemetry answering a request this client did not make

    @property
    def session(self) -> bytes | None:
        return None if self.keys is None else self.keys.session

    def _send(self, dtype: int, payload: bytes = b"") -> float:
        now = time.monotonic()
        if dtype != P.UdpType.HELLO and self.keys is not None and now - self.last_sent_at > self.SESSION_IDLE:
            if dtype == P.UdpType.STOP:  # a stop goes out anyway: it acts if the session still lives
                self._transmit(dtype, payload, self.keys)
            self.keys = None  # silent too long: the agent has expired the session
        keys = self._hello_keys if dtype == P.UdpType.HELLO else self.keys
        if keys is None:
            self.unsent += 1
            self.hello()
            return time.monotonic()
        if dtype != P.UdpType.HELLO:
            self.last_sent_at = now
        self._transmit(dtype, payload, keys)
        return time.monotonic()

    def _transmit(self, dtype: int, payload: bytes, keys: P.LinkKeys) -> None:
        self.counter += 1
        wire = P.encode_datagram(P.Datagram(dtype, self.sender, self.epoch, self.counter, payload), keys)
        try:
            self.sock.sendto(wire, self.address)
        except OSError:
            self.send_errors += 1  # e.g. no route while a cable is out: the watchdogs stop the robot

    def hello(self) -> None:
        """Ask the agent for its session id (rate-limited to one per HELLO_INTERVAL)."""
        now = time.monotonic()
        if now - self.last_hello_at < self.HELLO_INTERVAL:
            return
        self.last_hello_at = now
        self._hello_nonce = random.getrandbits(64)
        self._send(P.UdpType.HELLO, P.hello_payload(self._hello_nonce))

    def command(self, right: int, left: int) -> float:
        """Send a speed command; returns the monotonic time it left."""
        return self._send(P.UdpType.COMMAND, P.command_payload(right, left))

    def stop(self) -> float:
        return self._send(P.UdpType.STOP)

    def claim_control(self, timeout: float = 10.0) -> bool:
        """TAKE_OVER until the agent's telemetry names this host the controlling one."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.take_over()
            if self.telemetry_until(min(1.0, max(0.0, deadline - time.monotonic())),
                                    lambda body: body.get("controller") == self.sender) is not None:
                return True
        return False

    def take_over(self) -> float:
        """Become the controlling host of the agent (the robot stops; the host that had
        control sees it in telemetry and stops its trial)."""
        return self._send(P.UdpType.TAKE_OVER)

    def set_trim(self, servo: int, neutral_us: int, direction: int) -> float:
        """Ask the agent to set a servo's trim (0 right, 1 left); it forwards it to the
        firmware only while the robot is stopped. Raises :class:`LinkError` for a trim the
        firmware would refuse."""
        try:
            payload = P.trim_payload(servo, neutral_us, direction)
        except P.FrameError as exc:
            raise LinkError(str(exc)) from None
        return self._send(P.UdpType.SET_TRIM, payload)

    def request_telemetry(self) -> None:
        now = time.monotonic()
        if self.keys is None or (now - self.last_telemetry_at > self.RESYNC_AFTER
                                 and now - self.last_request_at < self.RESYNC_AFTER):
            self.hello()  # no session yet, or requests go unanswered: the agent may have restarted
        nonce = random.getrandbits(32)
        self.last_request_at = now
        if self.keys is not None:
            self._nonces.append(nonce)
            self._send(P.UdpType.TELEMETRY_REQUEST, P.nonce_payload(nonce))

    def _on_session(self, data: bytes, session: bytes) -> None:
        """A SESSION datagram claiming ``session`` (its key derives from that id)."""
        if self._hello_nonce is None:
            return
        keys = P.LinkKeys.derive(self.key, session)
        try:
            d = P.decode_datagram(data, keys, frozenset({P.UdpType.SESSION}))
        except P.DatagramError:
            return
        nonce, _ = P.unpack_session(d.payload)  # the session id in it is the one peeked and verified
        if nonce != self._hello_nonce:
            return  # an answer to an older HELLO (or a replayed one)
        self._hello_nonce = None
        self.last_sent_at = time.monotonic()  # the agent has just kept (or begun) this session
        if session != self.session:
            self.keys = keys
            self.sessions += 1
            self._last_telemetry_counter = None

    def poll(self) -> list[dict[str, Any]]:
        """Authenticated telemetry that arrived (others are ignored)."""
        out = []
        for _ in range(64):
            try:
                data, source = self.sock.recvfrom(P.MAX_DATAGRAM + 1)
            except (BlockingIOError, ConnectionRefusedError):
                break
            if source[0] != self.address[0]:
                continue
            session = P.peek_session(data)
            if session is not None:
                self._on_session(data, session)
                continue
            if self.keys is None:
                continue
            try:
                d = P.decode_datagram(data, self.keys, frozenset({P.UdpType.TELEMETRY}))
                body = json.loads(d.payload)
            except (P.DatagramError, json.JSONDecodeError, UnicodeDecodeError):
                continue
            stamp = (d.epoch, d.counter)
            if not isinstance(body, dict) or (self._last_telemetry_counter is not None
                                              and stamp <= self._last_telemetry_counter):
                continue  # not an object, or a replay of older telemetry
            if body.get("nonce") not in self._nonces:
                self.foreign_telemetry += 1
                continue  # an answer to a request this client did not make (another host's)
            self._last_telemetry_counter = stamp
            self.last_telemetry_at = time.monotonic()
            self.last_telemetry = body
            out.append(body)
        return out

    def telemetry_until(self, timeout: float, accept: Callable[[dict[str, Any]], bool]) -> dict[str, Any] | None:
        """Ask for telemetry every 0.5 s until a reply that ``accept``s comes (returned), or
        ``timeout`` s pass (None)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.request_telemetry()
            t_end = min(deadline, time.monotonic() + 0.5)
            while time.monotonic() < t_end:
                for body in self.poll():
                    if accept(body):
                        return body
                time.sleep(0.02)
        return None

    def silent_for(self, now: float) -> float:
        return now - self.last_telemetry_at

    def close(self) -> None:
        """Give up control of the robot (if this host had it), so the next host process may
        command it without --take-over, and close the socket."""
        if self.keys is not None:
            self._transmit(P.UdpType.RELEASE, b"", self.keys)
        self.sock.close()


def new_key(path: Path) -> None:
    """Write a fresh random key readable only by its owner."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(os.urandom(P.KEY_SIZE))


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A loopback port nothing is bound to now (UDP by default), for a local agent, world
    or pose source."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
