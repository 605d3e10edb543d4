"""The host's end of the UDP link to the Pi agent (docs/protocol.md, "UDP link").

Authenticated COMMAND and STOP datagrams out, TELEMETRY_REQUEST out and TELEMETRY back.
The epoch is the host's wall-clock second at start and the counter starts at the
nanosecond within that second, then rises by one per datagram. The agent accepts a
restarted host (a later second, or later in the same second than any datagram the old
one could have sent) and refuses replays.
"""

from __future__ import annotations

import json
import os
import random
import socket
import struct
import time
from pathlib import Path
from typing import Any

from tumblebot.errors import TumblebotError
from tumblebot.pi_agent import protocol as P


class LinkError(TumblebotError):
    """The agent address or key is unusable."""


def load_host_key(path: Path) -> bytes:
    """The shared 32-byte key; like the agent, refuse a file others may read."""
    try:
        st = path.stat()
    except FileNotFoundError:
        raise LinkError(f"key file {path} does not exist") from None
    if st.st_mode & 0o077:
        raise LinkError(f"key file {path} is readable by others (chmod 600 {path})")
    key = path.read_bytes()
    if len(key) != P.KEY_SIZE:
        raise LinkError(f"key file {path} holds {len(key)} bytes; the key is {P.KEY_SIZE} bytes")
    return key


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
    """Sends commands to one agent and tracks whether it answers."""

    def __init__(self, address: tuple[str, int], key: bytes, sender: int = 1) -> None:
        self.address, self.key, self.sender = address, key, sender
        now = time.time_ns()
        self.epoch = now // 1_000_000_000
        # A host restarted within the same second starts above anything the old one sent
        # (it cannot have sent more than one datagram per nanosecond).
        self.counter = now % 1_000_000_000
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("0.0.0.0", 0))
        self.sock.setblocking(False)
        self.last_telemetry_at = -1e9  #: monotonic time of the last authenticated TELEMETRY
        self.last_telemetry: dict[str, Any] = {}
        self.last_request_at = -1e9
        self._nonce = 0
        self.send_errors = 0

    def _send(self, dtype: int, payload: bytes = b"") -> float:
        self.counter += 1
        wire = P.encode_datagram(P.Datagram(dtype, self.sender, self.epoch, self.counter, payload), self.key)
        try:
            self.sock.sendto(wire, self.address)
        except OSError:
            self.send_errors += 1  # e.g. no route while a cable is out: the watchdogs stop the robot
        return time.monotonic()

    def command(self, right: int, left: int) -> float:
        """Send a speed command; returns the monotonic time it left."""
        return self._send(P.UdpType.COMMAND, struct.pack("<bb", right, left))

    def stop(self) -> float:
        return self._send(P.UdpType.STOP)

    def request_telemetry(self) -> None:
        self._nonce = random.getrandbits(32)
        self.last_request_at = time.monotonic()
        self._send(P.UdpType.TELEMETRY_REQUEST, struct.pack("<I", self._nonce))

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
            try:
                d = P.decode_datagram(data, self.key)
                body = json.loads(d.payload)
            except (P.DatagramError, json.JSONDecodeError, UnicodeDecodeError):
                continue
            if d.type != P.UdpType.TELEMETRY or not isinstance(body, dict):
                continue
            self.last_telemetry_at = time.monotonic()
            self.last_telemetry = body
            out.append(body)
        return out

    def silent_for(self, now: float) -> float:
        return now - self.last_telemetry_at

    def close(self) -> None:
        self.sock.close()


def new_key(path: Path) -> None:
    """Write a fresh random key readable only by its owner."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(os.urandom(P.KEY_SIZE))
