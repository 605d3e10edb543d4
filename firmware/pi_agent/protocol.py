"""tumblebot's wire protocol, Python side (the byte tables are in docs/protocol.md).

Two links:

* **serial** (agent ↔ Arduino): COBS-framed, 0x00-delimited frames carrying a version,
  the firmware's boot epoch, a sequence number, a message and a CRC-16/MCRF4XX;
* **UDP** (host → agent, and telemetry back): datagrams authenticated with a truncated
  HMAC-SHA256 under keys derived per direction and per agent session (:class:`LinkKeys`),
  carrying a sender id, a sender epoch and a strictly increasing counter.

This module imports nothing of tumblebot's and only the standard library, so the Pi
agent (and anything else) can use it alone. The C++ twin is
``firmware/arduino/lib/tumbleproto``; both are checked against
``firmware/protocol/vectors.txt``.
"""

from __future__ import annotations

import collections
import enum
import hashlib
import hmac
import os
import stat
import struct
from dataclasses import dataclass

# --------------------------------------------------------------------------- serial link
PROTOCOL_VERSION = 1
SERIAL_HEADER = struct.Struct("<BHHB")  # version, epoch, seq, type
SERIAL_HEADER_SIZE = SERIAL_HEADER.size  # 6
CRC_SIZE = 2
MAX_PAYLOAD = 20
MAX_BODY = SERIAL_HEADER_SIZE + MAX_PAYLOAD + CRC_SIZE  # 28
MAX_ENCODED = MAX_BODY + 1  # COBS adds one byte per 254; the 0x00 delimiter is extra
BAUD_RATE = 115_200


class MsgType(enum.IntEnum):
    """Serial message types. Agent → firmware below 0x80, firmware → agent from 0x80."""

    SET_SPEEDS = 0x01  #: payload: right i8, left i8, each −1 (reverse), 0 (stop), +1 (forward)
    PING = 0x02  #: payload: token u32
    SET_TRIM = 0x03  #: payload: servo u8 (0 right, 1 left), neutral_us u16, direction i8 (±1)
    GET_STATUS = 0x04  #: no payload
    GET_INFO = 0x05  #: no payload; answered with INFO
    READY = 0x80  #: payload: protocol u8, firmware major u8, minor u8, patch u8
    PONG = 0x81  #: payload: token u32
    STATUS = 0x82  #: payload: see :class:`Status`
    INFO = 0x83  #: payload: see :class:`Info` (versions and the trims in force)
    ERROR = 0x8F  #: payload: code u8, offending seq u16


class ErrorCode(enum.IntEnum):
    """Reasons a frame is refused (``ERROR`` payload, and decoder counters)."""

    OK = 0
    BAD_CRC = 1
    BAD_COBS = 2
    TOO_LONG = 3
    TOO_SHORT = 4
    BAD_VERSION = 5
    STALE_EPOCH = 6
    OLD_SEQUENCE = 7
    UNKNOWN_TYPE = 8
    BAD_PAYLOAD = 9


SET_SPEEDS_STRUCT = struct.Struct("<bb")
TOKEN_STRUCT = struct.Struct("<I")
TRIM_STRUCT = struct.Struct("<BHb")
READY_STRUCT = struct.Struct("<BBBB")
STATUS_STRUCT = struct.Struct("<IbbBHHHHH")
INFO_STRUCT = struct.Struct("<BBBBHbHb")
ERROR_STRUCT = struct.Struct("<BH")
#: The servo pulses the firmware drives (``tumble_config.h`` holds the same numbers; a test
#: keeps them equal): neutral, the offset of full speed (1000 / 2000 µs), and the range a
#: neutral trim may take.
NEUTRAL_US, FULL_SPEED_US = 1500, 500
NEUTRAL_MIN_US, NEUTRAL_MAX_US = 1300, 1700
#: How far a servo's own neutral may lie from nominal (the catalogue's servos stop within
#: 1480–1520 µs, and a trim pot adjusts a few tens of µs): ``bench check`` calls a trim
#: farther off an error.
NEUTRAL_SPREAD_US = 50


@dataclass(frozen=True)
class MessageSpec:
    """One row of the serial message table."""

    type: MsgType
    direction: str  #: "to_firmware" (agent → Arduino) or "to_agent" (Arduino → agent)
    size: int  #: exact payload size, bytes


#: The serial message table (docs/protocol.md, "Messages"); the C++ twin is
#: ``tumble::payloadSize`` / ``tumble::isForFirmware`` in tumble_proto.h.
MESSAGES: dict[MsgType, MessageSpec] = {m.type: m for m in (
    MessageSpec(MsgType.SET_SPEEDS, "to_firmware", SET_SPEEDS_STRUCT.size),
    MessageSpec(MsgType.PING, "to_firmware", TOKEN_STRUCT.size),
    MessageSpec(MsgType.SET_TRIM, "to_firmware", TRIM_STRUCT.size),
    MessageSpec(MsgType.GET_STATUS, "to_firmware", 0),
    MessageSpec(MsgType.GET_INFO, "to_firmware", 0),
    MessageSpec(MsgType.READY, "to_agent", READY_STRUCT.size),
    MessageSpec(MsgType.PONG, "to_agent", TOKEN_STRUCT.size),
    MessageSpec(MsgType.STATUS, "to_agent", STATUS_STRUCT.size),
    MessageSpec(MsgType.INFO, "to_agent", INFO_STRUCT.size),
    MessageSpec(MsgType.ERROR, "to_agent", ERROR_STRUCT.size),
)}
#: Payload sizes by type (exact), from the table.
PAYLOAD_SIZES: dict[MsgType, int] = {t: m.size for t, m in MESSAGES.items()}


class ProtocolError(ValueError):
    """A frame or datagram that does not decode."""


class FrameError(ProtocolError):
    """A serial frame refused; ``code`` says why."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code


def crc16_mcrf4xx(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/MCRF4XX: poly 0x1021 reflected (0x8408), init 0xFFFF, no final xor.

    ``crc16_mcrf4xx(b"123456789") == 0x6F91``.
    """
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0x8408 if crc & 1 else crc >> 1
    return crc & 0xFFFF


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: no 0x00 in the output (delimiter not added)."""
    out = bytearray([0])
    code_at, code = 0, 1
    for byte in data:
        if byte == 0:
            out[code_at] = code
            code_at, code = len(out), 1
            out.append(0)
        else:
            out.append(byte)
            code += 1
            if code == 0xFF:
                out[code_at] = code
                code_at, code = len(out), 1
                out.append(0)
    out[code_at] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises :class:`ProtocolError` (BAD_COBS)."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        end = i + code
        if code == 0 or end > n:
            raise FrameError(ErrorCode.BAD_COBS, f"COBS code {code} at offset {i} overruns the frame")
        block = data[i + 1:end]
        if 0 in block:
            raise FrameError(ErrorCode.BAD_COBS, "zero byte inside a COBS block")
        out += block
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


@dataclass(frozen=True)
class Frame:
    """A decoded serial frame."""

    epoch: int
    seq: int
    type: int
    payload: bytes = b""
    version: int = PROTOCOL_VERSION


def encode_frame(frame: Frame) -> bytes:
    """Frame → wire bytes (COBS, then the 0x00 delimiter)."""
    if len(frame.payload) > MAX_PAYLOAD:
        raise FrameError(ErrorCode.TOO_LONG, f"payload of {len(frame.payload)} bytes exceeds {MAX_PAYLOAD}")
    body = SERIAL_HEADER.pack(frame.version, frame.epoch & 0xFFFF, frame.seq & 0xFFFF, frame.type) + frame.payload
    body += struct.pack("<H", crc16_mcrf4xx(body))
    return cobs_encode(body) + b"\x00"


def decode_body(encoded: bytes) -> Frame:
    """One frame's bytes *without* the delimiter → :class:`Frame`.

    Checks length, COBS, CRC, version, known type and exact payload size. Epoch and
    sequence policy belong to the receiver (:class:`SequenceGuard`).
    """
    if len(encoded) > MAX_ENCODED:
        raise FrameError(ErrorCode.TOO_LONG, f"frame of {len(encoded)} bytes exceeds {MAX_ENCODED}")
    body = cobs_decode(encoded)
    if len(body) < SERIAL_HEADER_SIZE + CRC_SIZE:
        raise FrameError(ErrorCode.TOO_SHORT, f"frame body of {len(body)} bytes is too short")
    if len(body) > MAX_BODY:
        raise FrameError(ErrorCode.TOO_LONG, f"frame body of {len(body)} bytes exceeds {MAX_BODY}")
    (crc,) = struct.unpack_from("<H", body, len(body) - CRC_SIZE)
    if crc16_mcrf4xx(body[:-CRC_SIZE]) != crc:
        raise FrameError(ErrorCode.BAD_CRC, "CRC mismatch")
    version, epoch, seq, mtype = SERIAL_HEADER.unpack_from(body)
    if version != PROTOCOL_VERSION:
        raise FrameError(ErrorCode.BAD_VERSION, f"protocol version {version}, expected {PROTOCOL_VERSION}")
    payload = body[SERIAL_HEADER_SIZE:-CRC_SIZE]
    try:
        kind = MsgType(mtype)
    except ValueError:
        raise FrameError(ErrorCode.UNKNOWN_TYPE, f"unknown message type 0x{mtype:02x}") from None
    if len(payload) != PAYLOAD_SIZES[kind]:
        raise FrameError(ErrorCode.BAD_PAYLOAD, f"{kind.name} payload of {len(payload)} bytes, "
                                                   f"expected {PAYLOAD_SIZES[kind]}")
    if kind is MsgType.SET_SPEEDS and any(v not in (-1, 0, 1) for v in SET_SPEEDS_STRUCT.unpack(payload)):
        raise FrameError(ErrorCode.BAD_PAYLOAD, "speeds must be -1, 0 or +1")
    if kind is MsgType.SET_TRIM:
        check_trim(*unpack_trim(payload))
    return Frame(epoch, seq, mtype, bytes(payload), version)


class FrameDecoder:
    """Byte stream → frames. Bytes of an overlong frame are dropped up to the next
    delimiter; every refused frame is counted by reason in ``errors``."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._overflow = False
        self.errors: dict[ErrorCode, int] = dict.fromkeys(ErrorCode, 0)
        self.frames_ok = 0

    def feed(self, data: bytes) -> list[Frame]:
        frames: list[Frame] = []
        for byte in data:
            if byte != 0:
                if len(self._buffer) < MAX_ENCODED:
                    self._buffer.append(byte)
                else:
                    self._overflow = True
                continue
            if self._overflow:
                self.errors[ErrorCode.TOO_LONG] += 1
            elif self._buffer:
                try:
                    frames.append(decode_body(bytes(self._buffer)))
                    self.frames_ok += 1
                except FrameError as exc:
                    self.errors[exc.code] += 1
            self._buffer.clear()
            self._overflow = False
        return frames


def newer(seq: int, last: int) -> bool:
    """Whether 16-bit sequence ``seq`` comes after ``last`` (serial-number arithmetic)."""
    delta = (seq - last) & 0xFFFF
    return 0 < delta < 0x8000


# Serial payloads: every one is packed and unpacked here, nowhere else -------------------


def set_speeds_payload(right: int, left: int) -> bytes:
    if right not in (-1, 0, 1) or left not in (-1, 0, 1):
        raise FrameError(ErrorCode.BAD_PAYLOAD, f"speeds ({right}, {left}) must each be -1, 0 or +1")
    return SET_SPEEDS_STRUCT.pack(right, left)


def unpack_speeds(payload: bytes) -> tuple[int, int]:
    right, left = SET_SPEEDS_STRUCT.unpack(payload)
    return int(right), int(left)


def token_payload(token: int) -> bytes:
    """PING and PONG payload."""
    return TOKEN_STRUCT.pack(token & 0xFFFFFFFF)


def unpack_token(payload: bytes) -> int:
    return int(TOKEN_STRUCT.unpack(payload)[0])


SERVOS = ("right", "left")  #: servo numbers on both links: 0 right (D9), 1 left (D10)


def check_trim(servo: int, neutral_us: int, direction: int) -> None:
    """Raise :class:`FrameError` unless this is a trim the firmware accepts."""
    if servo not in (0, 1) or not NEUTRAL_MIN_US <= neutral_us <= NEUTRAL_MAX_US or direction not in (-1, 1):
        raise FrameError(ErrorCode.BAD_PAYLOAD, f"trim: servo 0 (right) or 1 (left), neutral {NEUTRAL_MIN_US}.."
                                                f"{NEUTRAL_MAX_US} us, direction +1 or -1; got {servo}, "
                                                f"{neutral_us}, {direction}")


def trim_payload(servo: int, neutral_us: int, direction: int) -> bytes:
    """SET_TRIM payload (the serial frame's and the UDP datagram's)."""
    check_trim(servo, neutral_us, direction)
    return TRIM_STRUCT.pack(servo, neutral_us, direction)


def unpack_trim(payload: bytes) -> tuple[int, int, int]:
    servo, neutral, direction = TRIM_STRUCT.unpack(payload)
    return int(servo), int(neutral), int(direction)


@dataclass(frozen=True)
class Ready:
    """READY payload: the firmware's protocol and version."""

    protocol: int
    major: int
    minor: int
    patch: int

    @classmethod
    def unpack(cls, payload: bytes) -> Ready:
        return cls(*READY_STRUCT.unpack(payload))

    def pack(self) -> bytes:
        return READY_STRUCT.pack(self.protocol, self.major, self.minor, self.patch)


@dataclass(frozen=True)
class Info:
    """INFO payload (10 bytes): the firmware's protocol and version, and the trims it holds
    (EEPROM), per servo (right, left): neutral pulse in µs and direction (±1)."""

    protocol: int
    major: int
    minor: int
    patch: int
    neutral_us: tuple[int, int]
    direction: tuple[int, int]

    @classmethod
    def unpack(cls, payload: bytes) -> Info:
        protocol, major, minor, patch, rn, rd, ln, ld = INFO_STRUCT.unpack(payload)
        return cls(protocol, major, minor, patch, (rn, ln), (rd, ld))

    def pack(self) -> bytes:
        return INFO_STRUCT.pack(self.protocol, self.major, self.minor, self.patch, self.neutral_us[0],
                                self.direction[0], self.neutral_us[1], self.direction[1])

    @property
    def version(self) -> str:
        return f"{self.major}.{self.minor}.{self.patch}"

    def trims(self) -> dict[str, dict[str, int]]:
        """``{"right": {"neutral_us": …, "direction": …}, "left": …}``, as telemetry carries them."""
        return {name: {"neutral_us": self.neutral_us[i], "direction": self.direction[i]}
                for i, name in enumerate(SERVOS)}


@dataclass(frozen=True)
class ErrorReport:
    """ERROR payload. ``code`` may be one this side does not know (a newer firmware):
    it is kept as a number and named ``unknown_0xNN``."""

    code: int
    seq: int

    @classmethod
    def unpack(cls, payload: bytes) -> ErrorReport:
        code, seq = ERROR_STRUCT.unpack(payload)
        return cls(int(code), int(seq))

    def pack(self) -> bytes:
        return ERROR_STRUCT.pack(self.code, self.seq)

    @property
    def name(self) -> str:
        try:
            return ErrorCode(self.code).name
        except ValueError:
            return f"unknown_0x{self.code:02x}"


@dataclass(frozen=True)
class Status:
    """Firmware status (``STATUS`` payload, 17 bytes, little-endian)."""

    uptime_ms: int
    right: int
    left: int
    flags: int  #: bit 0 armed (a valid command since boot), bit 1 watchdog holding neutral
    frames_ok: int
    crc_errors: int
    other_drops: int  #: every refused frame but CRC errors (COBS, length, version, epoch, seq, type, payload)
    watchdog_trips: int
    last_seq: int

    @classmethod
    def unpack(cls, payload: bytes) -> Status:
        return cls(*STATUS_STRUCT.unpack(payload))

    def pack(self) -> bytes:
        return STATUS_STRUCT.pack(self.uptime_ms, self.right, self.left, self.flags, self.frames_ok,
                                  self.crc_errors, self.other_drops, self.watchdog_trips, self.last_seq)


# ------------------------------------------------------------------------------ UDP link
UDP_MAGIC = b"TB"
UDP_VERSION = 2  #: 2: keys derived per direction and per agent session (docs/protocol.md)
UDP_HEADER = struct.Struct("<2sBBIIQ")  # magic, version, type, sender, epoch, counter
UDP_HEADER_SIZE = UDP_HEADER.size  # 20
MAC_SIZE = 16  #: HMAC-SHA256 truncated to 128 bits
MAX_DATAGRAM = 1024
KEY_SIZE = 32
SESSION_SIZE = 8
DEFAULT_PORT = 47800
COMMAND_STRUCT = struct.Struct("<bb")
NONCE_STRUCT = struct.Struct("<I")
HELLO_STRUCT = struct.Struct("<Q")
SESSION_STRUCT = struct.Struct("<Q8s")  # the HELLO's nonce, the agent's session id


class UdpType(enum.IntEnum):
    """Datagram types. Host → agent below 0x80, agent → host from 0x80."""

    COMMAND = 0x10  #: payload: right i8, left i8 (−1, 0, +1)
    STOP = 0x11  #: no payload
    TELEMETRY_REQUEST = 0x12  #: payload: nonce u32
    HELLO = 0x13  #: payload: nonce u64; asks for the agent's session id
    SET_TRIM = 0x14  #: payload: as the serial SET_TRIM (servo u8, neutral_us u16, direction i8)
    TAKE_OVER = 0x15  #: no payload; the sender becomes the controlling host (and the robot stops)
    RELEASE = 0x16  #: no payload; the controlling host gives up control (a host process says it as it ends)
    TELEMETRY = 0x90  #: payload: UTF-8 JSON object
    SESSION = 0x91  #: payload: the HELLO's nonce u64, session id 8 bytes


#: Exact payload sizes (None: any size up to the datagram limit).
UDP_PAYLOAD_SIZES: dict[UdpType, int | None] = {
    UdpType.COMMAND: COMMAND_STRUCT.size, UdpType.STOP: 0, UdpType.TELEMETRY_REQUEST: NONCE_STRUCT.size,
    UdpType.HELLO: HELLO_STRUCT.size, UdpType.SET_TRIM: TRIM_STRUCT.size, UdpType.TAKE_OVER: 0, UdpType.RELEASE: 0,
    UdpType.TELEMETRY: None, UdpType.SESSION: SESSION_STRUCT.size,
}
TO_AGENT: frozenset[UdpType] = frozenset(t for t in UdpType if t < 0x80)
TO_HOST: frozenset[UdpType] = frozenset(t for t in UdpType if t >= 0x80)


class DropReason(enum.Enum):
    """Why a receiver dropped a datagram (counted per reason)."""

    FOREIGN_HOST = "foreign_host"  #: from an address other than the allowed host (checked first)
    #: bad size, magic or version; a type unknown or not meant for this receiver; a payload of the wrong size
    MALFORMED = "malformed"
    UNAUTHENTICATED = "unauthenticated"  #: MAC mismatch under the key of this direction and session (constant time)
    OUT_OF_RANGE = "out_of_range"  #: payload values outside their range
    STALE = "stale"  #: an epoch older than the newest seen from this sender
    REPLAYED = "replayed"  #: counter not above the last one seen for this sender and epoch
    RATE_LIMITED = "rate_limited"  #: over a message type's rate limit, or superseded within the 100 ms slot
    BUSY = "busy"  #: a SET_TRIM while the robot is commanded to move (trims change only at rest)
    NOT_IN_CONTROL = "not_in_control"  #: a COMMAND or SET_TRIM from a host other than the controlling one


class DatagramError(ProtocolError):
    """A datagram refused; ``code`` says why."""

    def __init__(self, code: DropReason, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Datagram:
    type: int
    sender: int
    epoch: int
    counter: int
    payload: bytes = b""
    version: int = UDP_VERSION


class KeyFileError(ValueError):
    """A key file that is missing, unreadable, the wrong size, or open to others."""


MIN_KEY_DISTINCT_BYTES = 12  #: a random 32-byte key has about 30; fewer than this is not random


def read_key_file(path: str | os.PathLike[str]) -> bytes:
    """The 32-byte shared key from ``path``; refuses what is not a regular file (a FIFO
    would block the reader for ever), a file with any permission bit for group or others
    (the agent's and the host's rule alike), and a key that is clearly not random (all
    zeros, one byte repeated, a short pattern)."""
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            raise KeyFileError(f"key file {path} is not a regular file")
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # never hangs, even if swapped for a FIFO
        with os.fdopen(fd, "rb") as fh:
            data = fh.read(KEY_SIZE + 1)
    except FileNotFoundError:
        raise KeyFileError(f"key file {path} does not exist") from None
    except OSError as exc:
        raise KeyFileError(f"key file {path} cannot be read: {exc.strerror}") from None
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise KeyFileError(f"key file {path} is accessible by group or others (chmod 600 {path})")
    if len(data) != KEY_SIZE:
        size = str(len(data)) if len(data) <= KEY_SIZE else "more"
        raise KeyFileError(f"key file {path} must hold exactly {KEY_SIZE} bytes, not {size}")
    if len(set(data)) < MIN_KEY_DISTINCT_BYTES:
        raise KeyFileError(f"key file {path} is not a random key ({len(set(data))} distinct byte values in "
                           f"{KEY_SIZE}): make one with head -c 32 /dev/urandom")
    return data


def _hmac(key: bytes, data: bytes) -> bytes:
    return hmac.new(key, data, hashlib.sha256).digest()


def pose_key(key: bytes) -> bytes:
    """The key of the signed pose stream (docs/protocol.md, "Pose stream"):
    ``HMAC-SHA256(K, "tumblebot/2 pose")``, so a pose signature never verifies as a command."""
    return _hmac(key, b"tumblebot/2 pose")


def pose_tag(pose_key_: bytes, body: bytes) -> str:
    """The 32 hex digits that sign a pose datagram's JSON ``body``."""
    return _hmac(pose_key_, body)[:MAC_SIZE].hex()


@dataclass(frozen=True)
class LinkKeys:
    """The keys of one agent session, derived from the shared key (HKDF-style labels):

    * ``hello``: HMAC(K, "tumblebot/2 hello"), for HELLO only (there is no session yet);
    * ``to_agent``: HMAC(K, "tumblebot/2 host->agent" ‖ session), every other host → agent type;
    * ``to_host``: HMAC(K, "tumblebot/2 agent->host" ‖ session), every agent → host type.

    A datagram of one direction never verifies in the other (no reflection), and one
    from another agent session never verifies in this one (no replay after a restart).
    """

    hello: bytes
    to_agent: bytes
    to_host: bytes
    session: bytes

    @classmethod
    def derive(cls, key: bytes, session: bytes) -> LinkKeys:
        if len(key) != KEY_SIZE:
            raise ValueError(f"the shared key must be {KEY_SIZE} bytes, not {len(key)}")
        if len(session) != SESSION_SIZE:
            raise ValueError(f"a session id is {SESSION_SIZE} bytes, not {len(session)}")
        return cls(_hmac(key, b"tumblebot/2 hello"), _hmac(key, b"tumblebot/2 host->agent" + session),
                   _hmac(key, b"tumblebot/2 agent->host" + session), session)

    def for_type(self, dtype: int) -> bytes:
        if dtype == UdpType.HELLO:
            return self.hello
        return self.to_host if dtype >= 0x80 else self.to_agent


def encode_datagram(datagram: Datagram, keys: LinkKeys) -> bytes:
    body = UDP_HEADER.pack(UDP_MAGIC, datagram.version, datagram.type, datagram.sender, datagram.epoch,
                           datagram.counter) + datagram.payload
    if len(body) + MAC_SIZE > MAX_DATAGRAM:
        raise DatagramError(DropReason.MALFORMED, "datagram too long")
    return body + _hmac(keys.for_type(datagram.type), body)[:MAC_SIZE]


def decode_datagram(data: bytes, keys: LinkKeys, accept: frozenset[UdpType]) -> Datagram:
    """Check, in this order: size, magic and version, that the type is one of ``accept``
    (the types meant for this receiver), the MAC under that type's key (constant time,
    before anything else is trusted), the payload size and the payload ranges. Replay
    policy is :class:`ReplayGuard`'s; the source address is the caller's."""
    if not UDP_HEADER_SIZE + MAC_SIZE <= len(data) <= MAX_DATAGRAM:
        raise DatagramError(DropReason.MALFORMED, f"datagram of {len(data)} bytes")
    body, tag = data[:-MAC_SIZE], data[-MAC_SIZE:]
    magic, version, dtype, sender, epoch, counter = UDP_HEADER.unpack_from(body)
    if magic != UDP_MAGIC or version != UDP_VERSION:
        raise DatagramError(DropReason.MALFORMED, f"magic {magic!r} version {version}")
    if dtype not in accept:
        raise DatagramError(DropReason.MALFORMED, f"datagram type 0x{dtype:02x} is not for this receiver")
    kind = UdpType(dtype)
    if not hmac.compare_digest(_hmac(keys.for_type(kind), body)[:MAC_SIZE], tag):
        raise DatagramError(DropReason.UNAUTHENTICATED, "MAC mismatch")
    payload = bytes(body[UDP_HEADER_SIZE:])
    size = UDP_PAYLOAD_SIZES[kind]
    if size is not None and len(payload) != size:
        raise DatagramError(DropReason.MALFORMED, f"{kind.name} payload of {len(payload)} bytes, expected {size}")
    if kind is UdpType.COMMAND and any(v not in (-1, 0, 1) for v in COMMAND_STRUCT.unpack(payload)):
        raise DatagramError(DropReason.OUT_OF_RANGE, "speeds must be -1, 0 or +1")
    if kind is UdpType.SET_TRIM:
        try:
            check_trim(*unpack_trim(payload))
        except FrameError as exc:
            raise DatagramError(DropReason.OUT_OF_RANGE, str(exc)) from None
    return Datagram(dtype, sender, epoch, counter, payload, version)


def command_payload(right: int, left: int) -> bytes:
    if right not in (-1, 0, 1) or left not in (-1, 0, 1):
        raise DatagramError(DropReason.OUT_OF_RANGE, f"speeds ({right}, {left}) must each be -1, 0 or +1")
    return COMMAND_STRUCT.pack(right, left)


def unpack_command(payload: bytes) -> tuple[int, int]:
    right, left = COMMAND_STRUCT.unpack(payload)
    return int(right), int(left)


def nonce_payload(nonce: int) -> bytes:
    """TELEMETRY_REQUEST payload."""
    return NONCE_STRUCT.pack(nonce & 0xFFFFFFFF)


def unpack_nonce(payload: bytes) -> int:
    return int(NONCE_STRUCT.unpack(payload)[0])


def hello_payload(nonce: int) -> bytes:
    return HELLO_STRUCT.pack(nonce & 0xFFFFFFFFFFFFFFFF)


def unpack_hello(payload: bytes) -> int:
    return int(HELLO_STRUCT.unpack(payload)[0])


def session_payload(nonce: int, session: bytes) -> bytes:
    return SESSION_STRUCT.pack(nonce & 0xFFFFFFFFFFFFFFFF, session)


def unpack_session(payload: bytes) -> tuple[int, bytes]:
    nonce, session = SESSION_STRUCT.unpack(payload)
    return int(nonce), bytes(session)


def peek_session(data: bytes) -> bytes | None:
    """The session id a SESSION datagram claims, read *before* its MAC can be checked
    (its key derives from that id); ``None`` if ``data`` is not shaped like one."""
    if len(data) != UDP_HEADER_SIZE + SESSION_STRUCT.size + MAC_SIZE:
        return None
    magic, version, dtype, *_ = UDP_HEADER.unpack_from(data)
    if magic != UDP_MAGIC or version != UDP_VERSION or dtype != UdpType.SESSION:
        return None
    return bytes(data[UDP_HEADER_SIZE + 8:UDP_HEADER_SIZE + 16])


MAX_SENDERS = 32  #: replay state is kept for this many sender ids; the least recently accepted is evicted


class ReplayGuard:
    """Per sender: the newest epoch and the highest counter in it, for at most
    :data:`MAX_SENDERS` senders (least recently accepted evicted first; ``evicted``
    counts them). Call :meth:`check` only on datagrams whose MAC verified; it updates
    state only when it accepts.

    Eviction must not reopen replay: a flood of captured datagrams from many old sender
    ids would otherwise push a host's state out and let its own old datagrams in again.
    So the guard remembers the newest epoch it ever evicted (``floor``), and a sender it
    does not know is accepted only with a newer epoch. A host evicted by such a flood is
    then refused as well, until it restarts with a new epoch: a flood can stop the robot,
    never move it."""

    def __init__(self, max_senders: int = MAX_SENDERS) -> None:
        self._state: collections.OrderedDict[int, tuple[int, int]] = collections.OrderedDict()
        self.max_senders = max_senders
        self.evicted = 0
        self.floor = -1  #: the newest epoch of any evicted sender; unknown senders must be newer

    def check(self, d: Datagram) -> DropReason | None:
        last = self._state.get(d.sender)
        if last is not None:
            epoch, counter = last
            if d.epoch < epoch:
                return DropReason.STALE
            if d.epoch == epoch and d.counter <= counter:
                return DropReason.REPLAYED
        elif d.epoch <= self.floor:
            return DropReason.STALE
        self._state[d.sender] = (d.epoch, d.counter)
        self._state.move_to_end(d.sender)
        while len(self._state) > self.max_senders:
            _, (epoch, _) = self._state.popitem(last=False)
            self.floor = max(self.floor, epoch)
            self.evicted += 1
        return None

    def __len__(self) -> int:
        return len(self._state)
