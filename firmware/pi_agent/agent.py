"""The Raspberry Pi agent: authenticated UDP commands in, framed serial commands out.

Run ``tumblebot-agent --config /etc/tumblebot/agent.toml``. Needs pyserial and the
standard library only. Behaviour (docs/protocol.md has the wire formats):

* binds to the configured address and port only, and takes datagrams from the allowed
  host only; every datagram is authenticated (HMAC-SHA256) before anything else, under
  keys derived for this agent session and for the host → agent direction, so neither
  datagrams captured before a restart nor the agent's own telemetry reflected back act;
* draws a fresh random session id at start and tells it to a host that sends HELLO;
* acts on at most 10 commands per second: a command arriving sooner is held and the
  latest one wins at the next slot; a STOP acts at once unless the robot is already
  stopped (then it is dropped as rate-limited);
* resends the current command to the Arduino every 100 ms (the firmware's watchdog
  stops the servos 250 ms after the last one) and PINGs it every 100 ms, whatever the
  command rate;
* one host controls the robot at a time (the first to command it; another takes over only
  with TAKE_OVER, or after 2 s of its silence); anyone with the key may stop it or watch;
* commands stop when no valid datagram has arrived from the controlling host for 1 s, and
  the session expires then (a new session id): a command delivered late, after the host
  fell silent, never verifies;
* after opening the port (which resets an Uno) it waits for READY and adopts the boot
  epoch; any later firmware frame with another epoch is adopted as the live one. Its
  sequence numbers keep rising across epochs (a booted firmware takes any first seq), and
  an OLD_SEQUENCE error makes them jump ahead by a quarter of the circle;
* a serial device that errors, or that sends no frame at all for 1 s, is closed and
  reopened with back-off (0.25 s doubling to 4 s); no serial input ever ends the agent
  (frames it cannot use are counted in ``serial_drops``);
* forwards SET_TRIM to the Arduino (which stores it in EEPROM and answers INFO) only
  while the robot is stopped, at most 2 a second; asks the Arduino for INFO (firmware
  version and trims) after every boot, and reports both in telemetry's ``firmware``;
* answers TELEMETRY_REQUEST (at most 20 a second) with a JSON telemetry datagram: link
  loss over the last 100 pings, datagram drops by reason, round-trip times, the
  firmware's last STATUS.
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import os
import select
import socket
import struct
import sys
import time
import tomllib
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from tumblebot.pi_agent import protocol as P

log = logging.getLogger("tumblebot.agent")

COMMAND_INTERVAL = 0.1  #: s, at most 10 commands per second
KEEPALIVE_INTERVAL = 0.1  #: s, resend the current command to the Arduino
PING_INTERVAL = 0.1  #: s between PINGs, whatever the command rate
STATUS_INTERVAL = 1.0  #: s, ask the Arduino for its STATUS (reported in telemetry)
INFO_INTERVAL = 0.5  #: s, ask the Arduino for its INFO (version, trims) until it answers
TRIM_INTERVAL = 0.5  #: s, at most 2 SET_TRIMs a second (each one writes the Arduino's EEPROM)
TELEMETRY_INTERVAL = 0.05  #: s, at most 20 telemetry replies per second
HOST_TIMEOUT = 1.0  #: s without a valid datagram: stop
#: s of silence after which the controlling host's control lapses (its robot stopped a second
#: earlier): a host restarted after a crash resumes, and telemetry says nobody is in control
CONTROL_IDLE = 2.0
SERIAL_SILENCE = 1.0  #: s without any frame from the Arduino while pinging: reconnect
SEQ_JUMP = 0x4000  #: how far the sequence jumps on OLD_SEQUENCE (at most three jumps get past any last seq)
READY_TIMEOUT = 3.0  #: s to wait for READY after opening the port
PROBE_AFTER = 0.6  #: s without READY before probing for the epoch (a port that does not reset the Uno)
BACKOFF_MIN, BACKOFF_MAX = 0.25, 4.0  #: s, reconnect back-off


class AgentError(Exception):
    """A configuration or key problem; the command prints it as one line."""


@dataclass(frozen=True)
class AgentConfig:
    serial_port: str = "/dev/ttyACM0"  #: a pyserial URL (a device path, loop://, socket://…)
    baud: int = P.BAUD_RATE
    bind_address: str = "0.0.0.0"
    bind_port: int = P.DEFAULT_PORT
    allowed_host: str = "127.0.0.1"  #: datagrams from any other address are dropped
    key_file: str = "/etc/tumblebot/agent.key"
    agent_id: int = 1  #: sender id of telemetry datagrams

    @classmethod
    def load(cls, path: Path) -> AgentConfig:
        try:
            data = tomllib.loads(path.read_text())
        except FileNotFoundError:
            raise AgentError(f"config file {path} does not exist") from None
        except tomllib.TOMLDecodeError as exc:
            raise AgentError(f"config file {path} is not valid TOML: {exc}") from None
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise AgentError(f"config file {path}: unknown keys {', '.join(unknown)}")
        for name, value in data.items():
            expected = type(getattr(cls(), name))
            if type(value) is not expected:
                raise AgentError(f"config file {path}: {name} must be a {expected.__name__}, not {value!r}")
        config = cls(**data)
        if not 0 < config.bind_port < 65536:
            raise AgentError(f"bind_port {config.bind_port} is not a UDP port")
        try:
            socket.inet_pton(socket.AF_INET, config.allowed_host)
        except OSError:
            raise AgentError(f"allowed_host {config.allowed_host!r} must be an IPv4 address") from None
        return config


def load_key(path: Path) -> bytes:
    """Read the 32-byte shared key; refuse a file others can read or write."""
    try:
        return P.read_key_file(path)
    except P.KeyFileError as exc:
        raise AgentError(str(exc)) from None


SerialFactory = Callable[[str, int], Any]


def open_serial(url: str, baud: int) -> Any:
    import serial

    return serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=0.5)


class SerialLink:
    """The Arduino end: connection state, epoch, sequence numbers, pings, status."""

    def __init__(self, url: str, baud: int, factory: SerialFactory = open_serial) -> None:
        self.url, self.baud, self.factory = url, baud, factory
        self.port: Any = None
        self.decoder = P.FrameDecoder()
        self.epoch: int | None = None
        self.seq = 0
        self.opened_at = 0.0
        self.last_rx = 0.0
        self.next_attempt = 0.0
        self.backoff = BACKOFF_MIN
        self.pings: collections.deque[tuple[int, float, float | None]] = collections.deque(maxlen=100)
        self.ping_token = 0
        self.status: P.Status | None = None
        self.ready_info: P.Ready | None = None  #: the last READY: the firmware's version at boot
        self.info: P.Info | None = None  #: the last INFO: version and trims; None until asked in this epoch
        self.last_info_request = -1e9
        self.reconnects = 0
        self.errors_reported: collections.Counter[str] = collections.Counter()
        self.drops: collections.Counter[str] = collections.Counter()  #: serial frames not used, by reason
        self.jumped_at: int | None = None  #: first seq sent after the last OLD_SEQUENCE jump
        self.last_probe = -1e9
        self.last_speeds: float | None = None  #: when SET_SPEEDS was last written
        self.speeds_gap_max = 0.0  #: s, the longest the Arduino went without SET_SPEEDS from us

    @property
    def ready(self) -> bool:
        return self.port is not None and self.epoch is not None

    def poll(self, now: float) -> None:
        """Open if closed (with back-off), read what arrived, detect a dead link."""
        if self.port is None:
            if now >= self.next_attempt:
                self._open(now)
            return
        try:
            data = self.port.read(self.port.in_waiting or 1)
        except OSError as exc:  # pyserial's SerialException is an OSError
            self._lost(now, f"read failed: {exc}")
            return
        if data:
            for frame in self.decoder.feed(data):
                try:
                    self._on_frame(frame, now)
                except (P.ProtocolError, struct.error, ValueError) as exc:  # never die on serial input
                    log.debug("unusable frame %r: %s", frame, exc)
                    self.drops["unusable"] += 1
        if self.epoch is None and now - self.opened_at > READY_TIMEOUT:
            self._lost(now, "no READY after opening the port")
        elif self.epoch is None and now - self.opened_at > PROBE_AFTER and now - self.last_probe >= PROBE_AFTER:
            self._probe(now)
        elif self.epoch is not None and now - self.last_rx > SERIAL_SILENCE:
            self._lost(now, f"no frame from the Arduino for {SERIAL_SILENCE} s")

    def _open(self, now: float) -> None:
        try:
            self.port = self.factory(self.url, self.baud)
        except (OSError, ValueError) as exc:  # a missing device, or a malformed URL
            log.warning("cannot open %s: %s (retry in %.2f s)", self.url, exc, self.backoff)
            self.next_attempt = now + self.backoff
            self.backoff = min(self.backoff * 2, BACKOFF_MAX)
            return
        log.info("opened %s, waiting for READY", self.url)
        self.decoder = P.FrameDecoder()
        self.epoch = None
        self.info = None
        self.opened_at = self.last_rx = now

    def _probe(self, now: float) -> None:
        """No READY: the Arduino did not reset when the port opened (it already heard an
        agent). A GET_STATUS with a guessed epoch is answered with STATUS or an ERROR,
        either of which carries the live epoch in its header."""
        self.last_probe = now
        self._write(0, P.MsgType.GET_STATUS, b"", now)

    def _lost(self, now: float, why: str) -> None:
        log.warning("serial link lost: %s", why)
        try:
            if self.port is not None:
                self.port.close()
        except OSError:  # closing a vanished device may fail too
            pass
        self.port = None
        self.epoch = None
        self.last_speeds = None  # a gap across a reconnect is not the Pi being slow
        self.reconnects += 1
        self.next_attempt = now + self.backoff
        self.backoff = min(self.backoff * 2, BACKOFF_MAX)

    def _on_frame(self, frame: P.Frame, now: float) -> None:
        if frame.type < 0x80:  # an agent -> firmware type on the way in: an echo, never ours
            self.drops["wrong_direction"] += 1
            return
        self.last_rx = now
        if frame.epoch != self.epoch:
            if self.epoch is not None:
                log.warning("frame from epoch %d while in %d: adopting it (the Arduino rebooted)",
                            frame.epoch, self.epoch)
            else:
                log.info("firmware epoch %d", frame.epoch)
            self.epoch = frame.epoch  # READY, and every reply, carries the live epoch
            self.info = None  # another boot: ask again (its trims may differ)
        if frame.type == P.MsgType.READY:
            self.backoff = BACKOFF_MIN
            self.ready_info = P.Ready.unpack(frame.payload)
        elif frame.type == P.MsgType.INFO:
            self.info = P.Info.unpack(frame.payload)
        elif frame.type == P.MsgType.PONG:
            token = P.unpack_token(frame.payload)
            for i, (t, sent, _) in enumerate(self.pings):
                if t == token:
                    self.pings[i] = (t, sent, now - sent)
                    break
        elif frame.type == P.MsgType.STATUS:
            self.status = P.Status.unpack(frame.payload)
        elif frame.type == P.MsgType.ERROR:
            report = P.ErrorReport.unpack(frame.payload)
            self.errors_reported[report.name] += 1
            if report.code == P.ErrorCode.OLD_SEQUENCE:
                self._resync(report.seq)

    def _resync(self, refused: int) -> None:
        """Our seq is behind the firmware's last accepted one (the agent restarted on a
        port that does not reset the Arduino): jump ahead, once per round of refusals."""
        if self.jumped_at is not None and not (refused == self.jumped_at or P.newer(refused, self.jumped_at)):
            return  # refused before the last jump took effect
        self.seq = (self.seq + SEQ_JUMP) & 0xFFFF
        self.jumped_at = (self.seq + 1) & 0xFFFF
        log.warning("firmware refused seq %d as old: jumping to %d", refused, self.jumped_at)

    def send(self, mtype: P.MsgType, payload: bytes, now: float) -> bool:
        if not self.ready:
            return False
        assert self.epoch is not None
        return self._write(self.epoch, mtype, payload, now)

    def _write(self, epoch: int, mtype: P.MsgType, payload: bytes, now: float) -> bool:
        """One frame with the next seq; a failed write loses the link."""
        self.seq = (self.seq + 1) & 0xFFFF
        try:
            # A leading delimiter ends any garbage the Arduino may hold, so this frame decodes.
            self.port.write(b"\x00" + P.encode_frame(P.Frame(epoch, self.seq, mtype, payload)))
        except OSError as exc:  # includes pyserial's write timeout
            self._lost(now, f"write failed: {exc}")
            return False
        return True

    def send_speeds(self, right: int, left: int, now: float) -> bool:
        sent = self.send(P.MsgType.SET_SPEEDS, P.set_speeds_payload(right, left), now)
        if sent:
            if self.last_speeds is not None:  # a starved Pi shows here before its Arduino's watchdog trips
                self.speeds_gap_max = max(self.speeds_gap_max, now - self.last_speeds)
            self.last_speeds = now
        return sent

    def request_info(self, now: float) -> None:
        """Ask for INFO while this epoch's is unknown (at most every INFO_INTERVAL)."""
        if self.ready and self.info is None and now - self.last_info_request >= INFO_INTERVAL:
            self.last_info_request = now
            self.send(P.MsgType.GET_INFO, b"", now)

    def firmware(self) -> dict[str, Any] | None:
        """What telemetry says of the firmware: protocol, version and trims (from INFO), or
        only the version from READY when INFO has not come (a firmware before 1.1.0)."""
        if self.info is not None:
            return {"protocol": self.info.protocol, "version": self.info.version, "trims": self.info.trims()}
        if self.ready_info is not None and self.ready:
            r = self.ready_info
            return {"protocol": r.protocol, "version": f"{r.major}.{r.minor}.{r.patch}", "trims": None}
        return None

    def ping(self, now: float) -> None:
        self.ping_token = (self.ping_token + 1) & 0xFFFFFFFF
        if self.send(P.MsgType.PING, P.token_payload(self.ping_token), now):
            self.pings.append((self.ping_token, now, None))

    def telemetry(self, now: float) -> dict[str, Any]:
        settled = [p for p in self.pings if now - p[1] > 0.5 or p[2] is not None]
        lost = sum(1 for p in settled if p[2] is None)
        rtts = sorted(p[2] for p in settled if p[2] is not None)
        return {
            "serial_connected": self.ready,
            "epoch": self.epoch,
            "link_loss": lost / len(settled) if settled else None,
            "rtt_ms": {"median": 1e3 * rtts[len(rtts) // 2], "max": 1e3 * rtts[-1]} if rtts else None,
            "reconnects": self.reconnects,
            "firmware_errors": dict(self.errors_reported),
            "serial_drops": {**{k.name: v for k, v in self.decoder.errors.items() if v and k != P.ErrorCode.OK},
                             **self.drops},
            "firmware_status": asdict(self.status) if self.status else None,
            "firmware": self.firmware(),
            "speeds_gap_max_ms": round(1e3 * self.speeds_gap_max, 1),
        }


class Agent:
    """UDP in, serial out. ``step()`` does one round of work; ``run()`` loops."""

    def __init__(self, config: AgentConfig, key: bytes, serial_factory: SerialFactory = open_serial) -> None:
        self.config, self.key = config, key
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((config.bind_address, config.bind_port))
        self.sock.setblocking(False)
        self.link = SerialLink(config.serial_port, config.baud, serial_factory)
        self.session = os.urandom(P.SESSION_SIZE)  #: fresh at every start: old datagrams never verify
        self.keys = P.LinkKeys.derive(key, self.session)
        self.session_used = False  #: a session datagram was accepted under this session id
        self.controller: int | None = None  #: sender id of the controlling host
        self.controller_seen = -1e9  #: when its last COMMAND, SET_TRIM or TAKE_OVER was accepted
        self.takeovers = 0
        self.controller_spoke = False  #: the controlling host sent something under this session
        self.last_hello = -1e9  #: a fresh HELLO keeps the session from expiring (not the robot moving)
        self.sessions_expired = 0
        self.guard = P.ReplayGuard()
        self.drops: collections.Counter[str] = collections.Counter()
        self.rate_limited: collections.Counter[str] = collections.Counter()  #: rate_limited drops by type
        self.accepted = 0
        self.host_timeouts = 0  #: stops because no valid datagram came for HOST_TIMEOUT
        self.command = (0, 0)  #: what the Arduino is being told
        self.pending: tuple[int, int] | None = None
        self.last_acted = -1e9
        self.last_valid = -1e9
        self.last_keepalive = -1e9
        self.last_status_request = -1e9
        self.last_ping = -1e9
        self.last_telemetry = -1e9
        self.hellos_answered = 0
        self.last_trim = -1e9
        self.trims_forwarded = 0
        now_ns = time.time_ns()
        self.epoch = now_ns // 1_000_000_000
        self.telemetry_counter = now_ns % 1_000_000_000

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()
        return host, port

    def _drop(self, reason: P.DropReason, dtype: int | None = None) -> None:
        self.drops[reason.value] += 1
        if reason is P.DropReason.RATE_LIMITED and dtype is not None:
            self.rate_limited[P.UdpType(dtype).name] += 1

    def handle_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        if source[0] != self.config.allowed_host:
            self._drop(P.DropReason.FOREIGN_HOST)
            return
        try:
            d = P.decode_datagram(data, self.keys, P.TO_AGENT)
        except P.DatagramError as exc:
            self._drop(exc.code)
            return
        reason = self.guard.check(d)  # HELLOs too: a captured one is answered at most once per agent run
        if reason is not None:
            self._drop(reason)
            return
        if d.type == P.UdpType.HELLO:  # not session-bound: answered, and the session kept, nothing else
            self.hellos_answered += 1
            self.last_hello = now
            self._reply(P.UdpType.SESSION, P.session_payload(P.unpack_hello(d.payload), self.session), source)
            return
        self.accepted += 1  # counted before acting, so a telemetry reply counts its own request
        self.last_valid = now
        self.session_used = True
        if d.sender == self.controller:
            self.controller_seen = now  # any datagram of the controlling host keeps its control
            self.controller_spoke = True
        if not self._act(d, source, now):
            self.accepted -= 1  # each datagram is counted once: accepted, or dropped for one reason

    def _in_control(self, d: P.Datagram, now: float) -> bool:
        """Whether ``d``'s sender may move the robot: the controlling host is the first to
        command it, and stays so while it sends anything at least every CONTROL_IDLE s;
        another sender takes control only with TAKE_OVER (or once that host has gone quiet)."""
        if d.type == P.UdpType.TAKE_OVER or self.controller is None or self.controller == d.sender \
                or now - self.controller_seen > CONTROL_IDLE:
            if self.controller is not None and self.controller != d.sender:
                log.warning("host sender %d takes control from sender %d%s", d.sender, self.controller,
                            " (TAKE_OVER)" if d.type == P.UdpType.TAKE_OVER else "")
                self.takeovers += 1
            self.controller, self.controller_seen, self.controller_spoke = d.sender, now, True
            return True
        self._drop(P.DropReason.NOT_IN_CONTROL, d.type)
        return False

    def _hand_over(self, d: P.Datagram, now: float) -> None:
        """TAKE_OVER: the sender controls the robot, which stops; RELEASE: the controlling
        host gives control up (the next host to command takes it)."""
        if d.type == P.UdpType.RELEASE:
            if self.controller == d.sender:
                self.controller = None
                self.pending = None
                if self.command != (0, 0):
                    self._apply((0, 0), now)  # nobody controls a moving robot
            return
        self._in_control(d, now)
        self.pending = None
        if self.command != (0, 0):
            self._apply((0, 0), now)  # the new host starts from a stopped robot

    def _act(self, d: P.Datagram, source: tuple[str, int], now: float) -> bool:
        """An authentic, fresh datagram from the host (liveness already refreshed); False
        when it is dropped after all (rate-limited, not the controlling host's, or a trim
        while moving). A STOP is taken from any key holder, and telemetry answered for any."""
        if d.type in (P.UdpType.TAKE_OVER, P.UdpType.RELEASE):
            self._hand_over(d, now)
            return True
        if d.type in (P.UdpType.COMMAND, P.UdpType.SET_TRIM) and not self._in_control(d, now):
            return False
        if d.type == P.UdpType.COMMAND:
            command = P.unpack_command(d.payload)
            if self.pending is None and command == self.command:
                return True  # the command in force, repeated: a keepalive, which must not delay the next change
            if self.pending is not None:  # the waiting one is superseded before it acted: it moves from
                self.accepted -= 1        # accepted to rate_limited
                self._drop(P.DropReason.RATE_LIMITED, d.type)
            self.pending = command
        elif d.type == P.UdpType.STOP:
            self.pending = None
            if self.command == (0, 0):
                self._drop(P.DropReason.RATE_LIMITED, d.type)  # already stopped: the keepalive repeats it
                return False
            self._apply((0, 0), now)  # a stop never waits for a slot
        elif d.type == P.UdpType.SET_TRIM:
            return self._trim(d, now)
        elif d.type == P.UdpType.TELEMETRY_REQUEST:
            if now - self.last_telemetry < TELEMETRY_INTERVAL:
                self._drop(P.DropReason.RATE_LIMITED, d.type)
                return False
            self.last_telemetry = now
            self._send_telemetry(source, P.unpack_nonce(d.payload), now)
        return True

    def _trim(self, d: P.Datagram, now: float) -> bool:
        """Forward a SET_TRIM, only at rest and at most every TRIM_INTERVAL (EEPROM writes)."""
        if self.command != (0, 0) or self.pending is not None:
            self._drop(P.DropReason.BUSY, d.type)  # a trim changes the pulses: only at rest
            return False
        if now - self.last_trim < TRIM_INTERVAL:
            self._drop(P.DropReason.RATE_LIMITED, d.type)
            return False
        self.last_trim = now
        if self.link.send(P.MsgType.SET_TRIM, d.payload, now):  # the firmware answers INFO
            self.trims_forwarded += 1
            self.link.info = None
        return True

    def _expire_session(self) -> None:
        """The host fell silent for HOST_TIMEOUT: a new session id, so no datagram it sent
        before (one lost or held back on the way, delivered late) can ever act; the host says
        HELLO again before it sends anything more (docs/protocol.md, "Keys and sessions")."""
        log.info("no valid datagram from the host for %.1f s: its session expires", HOST_TIMEOUT)
        self.session = os.urandom(P.SESSION_SIZE)
        self.keys = P.LinkKeys.derive(self.key, self.session)
        self.session_used = False
        self.controller_spoke = False
        self.sessions_expired += 1

    def _apply(self, command: tuple[int, int], now: float) -> None:
        self.command = command
        self.last_acted = now
        self.link.send_speeds(*command, now)
        self.last_keepalive = now

    def _reply(self, dtype: P.UdpType, payload: bytes, dest: tuple[str, int]) -> None:
        self.telemetry_counter += 1
        dgram = P.Datagram(dtype, self.config.agent_id, self.epoch, self.telemetry_counter, payload)
        try:
            self.sock.sendto(P.encode_datagram(dgram, self.keys), dest)
        except (OSError, P.DatagramError) as exc:
            log.warning("cannot send %s: %s", dtype.name, exc)

    def _send_telemetry(self, dest: tuple[str, int], nonce: int, now: float) -> None:
        body = {"nonce": nonce, "command": list(self.command), "accepted": self.accepted,
                "host_timeouts": self.host_timeouts, "drops": dict(self.drops), "rate_limited": dict(self.rate_limited),
                "senders": len(self.guard), "senders_evicted": self.guard.evicted,
                "trims_forwarded": self.trims_forwarded, "hellos_answered": self.hellos_answered,
                "sessions_expired": self.sessions_expired, "controller": self.controller,
                "takeovers": self.takeovers,
                **self.link.telemetry(now)}
        self._reply(P.UdpType.TELEMETRY, json.dumps(body, separators=(",", ":")).encode(), dest)

    def step(self, timeout: float = 0.01) -> None:
        readable, _, _ = select.select([self.sock], [], [], timeout)
        now = time.monotonic()
        if readable:
            for _ in range(64):  # drain, bounded
                try:
                    data, source = self.sock.recvfrom(P.MAX_DATAGRAM + 1)
                except BlockingIOError:
                    break
                self.handle_datagram(data, source, now)
        self.link.poll(now)
        if self.pending is not None and now - self.last_acted >= COMMAND_INTERVAL:
            command, self.pending = self.pending, None
            self._apply(command, now)
        if self.command != (0, 0) and now - self.controller_seen > HOST_TIMEOUT:
            # only the controlling host keeps the robot moving: another's telemetry requests do not
            log.warning("no valid datagram from the controlling host for %.1f s: stopping", HOST_TIMEOUT)
            self.host_timeouts += 1
            self.pending = None
            self._apply((0, 0), now)
        if self.controller is not None and now - self.controller_seen > CONTROL_IDLE:
            log.info("the controlling host (sender %d) has been silent %.0f s: nobody is in control",
                     self.controller, CONTROL_IDLE)
            self.controller = None
        host_silent = now - max(self.last_valid, self.last_hello) > HOST_TIMEOUT
        controller_silent = self.controller_spoke and now - self.controller_seen > HOST_TIMEOUT
        if self.session_used and (host_silent or controller_silent):
            self._expire_session()  # (even while another host talks: the controller's old datagrams never act)
        if now - self.last_keepalive >= KEEPALIVE_INTERVAL:
            self.last_keepalive = now
            self.link.send_speeds(*self.command, now)
        if now - self.last_ping >= PING_INTERVAL:  # liveness never depends on the command rate
            self.last_ping = now
            self.link.ping(now)
        if now - self.last_status_request >= STATUS_INTERVAL and self.link.ready:
            self.last_status_request = now
            self.link.send(P.MsgType.GET_STATUS, b"", now)
        self.link.request_info(now)

    def run(self, stop: Callable[[], bool] = lambda: False) -> None:
        log.info("listening on %s:%d for %s", *self.address, self.config.allowed_host)
        try:
            while not stop():
                self.step()
        finally:
            self.link.send_speeds(0, 0, time.monotonic())
            self.sock.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tumblebot-agent", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=Path("/etc/tumblebot/agent.toml"), help="TOML config file")
    parser.add_argument("--verbose", action="store_true", help="log every link event")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(message)s")
    try:
        config = AgentConfig.load(args.config)
        key = load_key(Path(config.key_file))
        agent = Agent(config, key)
    except (AgentError, OSError) as exc:
        print(f"tumblebot-agent: error: {exc}", file=sys.stderr)
        return 2
    try:
        agent.run()
    except KeyboardInterrupt:
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
