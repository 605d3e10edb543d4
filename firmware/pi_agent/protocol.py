"""tumblebot's wire protocol, Python side (the byte tables are in docs/protocol.md).

Two links:

* **serial** (agent ↔ Arduino): COBS-framed, 0x00-delimited frames carrying a version,
  the firmware's boot epoch, a sequence number, a message and a CRC-16/MCRF4XX;
* **UDP** (host → agent, and telemetry back): datagrams authenticated with a truncated
  HMAC-SHA256, carrying a sender id, a session epoch and a strictly increasing counter.

This module imports nothing of tumblebot's and only the standard library, so the Pi
agent (and anything else) can use it alone. The C++ twin is
``firmware/arduino/lib/tumbleproto``; both are checked against
``firmware/protocol/vectors.txt``.
"""

from __future__ import annotations

import enum
import hashlib
import hmac
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
    READY = 0x80  #: payload: protocol u8, firmware major u8, minor u8, patch u8
    PONG = 0x81  #: payload: token u32
    STATUS = 0x82  #: payload: see :class:`Status`
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


#: Payload sizes by type (exact).
PAYLOAD_SIZES: dict[MsgType, int] = {
    MsgType.SET_SPEEDS: 2, MsgType.PING: 4, MsgType.SET_TRIM: 4, MsgType.GET_STATUS: 0,
    MsgType.READY: 4, MsgType.PONG: 4, MsgType.STATUS: 17, MsgType.ERROR: 3,
}

STATUS_STRUCT = struct.Struct("<IbbBHHHHH")
TRIM_STRUCT = struct.Struct("<BHb")
ERROR_STRUCT = struct.Struct("<BH")
NEUTRAL_MIN_US, NEUTRAL_MAX_US = 1300, 1700


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
    if kind is MsgType.SET_SPEEDS and any(v not in (-1, 0, 1) for v in struct.unpack("<bb", payload)):
        raise FrameError(ErrorCode.BAD_PAYLOAD, "speeds must be -1, 0 or +1")
    if kind is MsgType.SET_TRIM:
        servo, neutral, direction = TRIM_STRUCT.unpack(payload)
        if servo > 1 or not NEUTRAL_MIN_US <= neutral <= NEUTRAL_MAX_US or direction not in (-1, 1):
            raise FrameError(ErrorCode.BAD_PAYLOAD, "trim: servo 0/1, neutral 1300..1700 us, direction ±1")
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


# payload helpers --------------------------------------------------------------------------
def set_speeds_payload(right: int, left: int) -> bytes:
    if right not in (-1, 0, 1) or left not in (-1, 0, 1):
        raise FrameError(ErrorCode.BAD_PAYLOAD, f"speeds ({right}, {left}) must each be -1, 0 or +1")
    return struct.pack("<bb", right, left)


@dataclass(frozen=True)
class Status:
    """Firmware status (``STATUS`` payload, 17 bytes, little-endian)."""

    uptime_ms: int
    right: int
    left: int
    flags: int  #: bit 0 armed (a valid command since boot), bit 1 watchdog holding neutral
    frames_ok: int
    crc_errors: int
    other_drops: int
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
UDP_HEADER = struct.Struct("<2sBBIIQ")  # magic, version, type, sender, epoch, counter
UDP_HEADER_SIZE = UDP_HEADER.size  # 20
MAC_SIZE = 16  #: HMAC-SHA256 truncated to 128 bits
MAX_DATAGRAM = 1024
KEY_SIZE = 32
DEFAULT_PORT = 47800


class UdpType(enum.IntEnum):
    COMMAND = 0x10  #: payload: right i8, left i8 (−1, 0, +1)
    STOP = 0x11  #: no payload
    TELEMETRY_REQUEST = 0x12  #: payload: nonce u32
    TELEMETRY = 0x90  #: agent → host, payload: UTF-8 JSON object


class DropReason(enum.Enum):
    """Why the agent dropped a datagram (counted per reason)."""

    MALFORMED = "malformed"  #: too short/long, bad magic or version
    UNAUTHENTICATED = "unauthenticated"  #: MAC mismatch (checked first, in constant time)
    REPLAYED = "replayed"  #: counter not above the last one seen for this sender and epoch
    STALE = "stale"  #: an epoch older than the newest seen from this sender
    OUT_OF_RANGE = "out_of_range"  #: unknown type or payload values outside their range
    FOREIGN_HOST = "foreign_host"  #: from an address other than the allowed host
    RATE_LIMITED = "rate_limited"  #: superseded by a newer command within the 100 ms slot


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
    version: int = PROTOCOL_VERSION


def _mac(key: bytes, data: bytes) -> bytes:
    return hmac.new(key, data, hashlib.sha256).digest()[:MAC_SIZE]


def encode_datagram(datagram: Datagram, key: bytes) -> bytes:
    if len(key) != KEY_SIZE:
        raise ValueError(f"the shared key must be {KEY_SIZE} bytes, not {len(key)}")
    body = UDP_HEADER.pack(UDP_MAGIC, datagram.version, datagram.type, datagram.sender, datagram.epoch,
                           datagram.counter) + datagram.payload
    if len(body) + MAC_SIZE > MAX_DATAGRAM:
        raise DatagramError(DropReason.MALFORMED, "datagram too long")
    return body + _mac(key, body)


def decode_datagram(data: bytes, key: bytes) -> Datagram:
    """Check size, magic, version and MAC (constant time, before anything else is
    trusted), then the type and payload. Replay policy is :class:`ReplayGuard`'s."""
    if not UDP_HEADER_SIZE + MAC_SIZE <= len(data) <= MAX_DATAGRAM:
        raise DatagramError(DropReason.MALFORMED, f"datagram of {len(data)} bytes")
    body, tag = data[:-MAC_SIZE], data[-MAC_SIZE:]
    if not hmac.compare_digest(_mac(key, body), tag):
        raise DatagramError(DropReason.UNAUTHENTICATED, "MAC mismatch")
    magic, version, dtype, sender, epoch, counter = UDP_HEADER.unpack_from(body)
    if magic != UDP_MAGIC or version != PROTOCOL_VERSION:
        raise DatagramError(DropReason.MALFORMED, f"magic {magic!r} version {version}")
    payload = body[UDP_HEADER_SIZE:]
    try:
        kind = UdpType(dtype)
    except ValueError:
        raise DatagramError(DropReason.OUT_OF_RANGE, f"unknown datagram type 0x{dtype:02x}") from None
    sizes = {UdpType.COMMAND: 2, UdpType.STOP: 0, UdpType.TELEMETRY_REQUEST: 4}
    if kind in sizes and len(payload) != sizes[kind]:
        raise DatagramError(DropReason.OUT_OF_RANGE, f"{kind.name} payload of {len(payload)} bytes")
    if kind is UdpType.COMMAND and any(v not in (-1, 0, 1) for v in struct.unpack("<bb", payload)):
        raise DatagramError(DropReason.OUT_OF_RANGE, "speeds must be -1, 0 or +1")
    return Datagram(dtype, sender, epoch, counter, bytes(payload), version)


class ReplayGuard:
    """Per sender: the newest epoch and the highest counter in it. Call :meth:`check`
    only on datagrams whose MAC verified; it updates state only when it accepts."""

    def __init__(self) -> None:
        self._state: dict[int, tuple[int, int]] = {}

    def check(self, d: Datagram) -> DropReason | None:
        last = self._state.get(d.sender)
        if last is not None:
            epoch, counter = last
            if d.epoch < epoch:
                return DropReason.STALE
            if d.epoch == epoch and d.counter <= counter:
                return DropReason.REPLAYED
        self._state[d.sender] = (d.epoch, d.counter)
        return None
