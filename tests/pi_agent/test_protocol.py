"""The Python protocol against the shared vectors, and the UDP authentication rules."""

from __future__ import annotations

import os
import random
import re
from pathlib import Path

import pytest

from tumblebot.pi_agent import protocol as P

VECTORS = Path(__file__).resolve().parents[2] / "firmware" / "protocol" / "vectors.txt"
KEY = bytes(range(32))


def unhex(text: str) -> bytes:
    return b"" if text == "-" else bytes.fromhex(text)


def vectors(kind: str) -> list[list[str]]:
    rows = [line.split() for line in VECTORS.read_text().splitlines() if line and not line.startswith("#")]
    return [r[1:] for r in rows if r[0] == kind]


def test_that_the_crc_has_the_mcrf4xx_check_value() -> None:
    assert P.crc16_mcrf4xx(b"123456789") == 0x6F91


@pytest.mark.parametrize("row", vectors("crc"))
def test_crc_vectors(row: list[str]) -> None:
    assert P.crc16_mcrf4xx(unhex(row[0])) == int(row[1], 16)


@pytest.mark.parametrize("row", vectors("cobs"))
def test_cobs_vectors(row: list[str]) -> None:
    raw, enc = unhex(row[0]), unhex(row[1])
    assert P.cobs_encode(raw) == enc
    assert P.cobs_decode(enc) == raw


@pytest.mark.parametrize("row", vectors("frame"))
def test_frame_vectors_encode_and_decode(row: list[str]) -> None:
    frame = P.Frame(int(row[0]), int(row[1]), int(row[2]), unhex(row[3]))
    wire = unhex(row[4])
    assert P.encode_frame(frame) == wire
    assert P.FrameDecoder().feed(wire) == [frame]


@pytest.mark.parametrize("row", vectors("reject"))
def test_reject_vectors(row: list[str]) -> None:
    with pytest.raises(P.FrameError) as info:
        P.decode_body(unhex(row[0]))
    assert info.value.code == P.ErrorCode[row[1]]
    decoder = P.FrameDecoder()
    assert decoder.feed(unhex(row[0]) + b"\x00") == []
    assert decoder.errors[P.ErrorCode[row[1]]] == 1


def test_that_the_vectors_file_is_what_the_generator_writes(tmp_path: Path) -> None:
    import subprocess
    import sys

    before = VECTORS.read_text()
    subprocess.run([sys.executable, str(VECTORS.with_name("make_vectors.py"))], check=True, capture_output=True)
    assert VECTORS.read_text() == before


def test_that_an_overlong_frame_is_discarded_and_the_next_frame_still_decodes() -> None:
    good = P.encode_frame(P.Frame(1, 2, P.MsgType.SET_SPEEDS, P.set_speeds_payload(1, 0)))
    decoder = P.FrameDecoder()
    frames = decoder.feed(b"\x07" * 500 + b"\x00" + good)
    assert len(frames) == 1
    assert decoder.errors[P.ErrorCode.TOO_LONG] == 1


def test_that_random_noise_never_decodes_into_a_set_speeds_frame() -> None:
    rng = random.Random(0)
    decoder = P.FrameDecoder()
    noise = bytes(rng.getrandbits(8) for _ in range(200_000))
    frames = decoder.feed(noise)
    # A random 16-bit CRC passes 1 in 65 536 times; with the version, type and payload
    # checks on top, random noise essentially never yields a frame.
    assert len(frames) <= 1


def test_sequence_numbers_wrap() -> None:
    assert P.newer(1, 0) and P.newer(0, 0xFFFF) and not P.newer(5, 5) and not P.newer(4, 5)
    assert P.newer(0x7FFF, 0) and not P.newer(0x8000, 0)  # exactly half the circle counts as old


SESSION = bytes(range(8))
KEYS = P.LinkKeys.derive(KEY, SESSION)


def command(counter: int, epoch: int = 100, sender: int = 7, speeds: tuple[int, int] = (1, -1)) -> P.Datagram:
    return P.Datagram(P.UdpType.COMMAND, sender, epoch, counter, P.command_payload(*speeds))


def refused(wire: bytes, keys: P.LinkKeys = KEYS, accept: frozenset[P.UdpType] = P.TO_AGENT) -> P.DropReason:
    with pytest.raises(P.DatagramError) as info:
        P.decode_datagram(wire, keys, accept)
    return info.value.code


def test_that_a_datagram_round_trips_with_its_keys() -> None:
    d = command(1)
    assert P.decode_datagram(P.encode_datagram(d, KEYS), KEYS, P.TO_AGENT) == d


def test_that_a_forged_or_tampered_datagram_is_unauthenticated() -> None:
    wire = bytearray(P.encode_datagram(command(1), KEYS))
    assert refused(bytes(wire), P.LinkKeys.derive(os.urandom(32), SESSION)) is P.DropReason.UNAUTHENTICATED
    wire[21] ^= 0x01  # flip a payload bit
    assert refused(bytes(wire)) is P.DropReason.UNAUTHENTICATED


def test_that_a_datagram_of_another_agent_session_is_unauthenticated() -> None:
    """Replay after an agent restart: the new session's keys differ."""
    wire = P.encode_datagram(command(1), KEYS)
    assert refused(wire, P.LinkKeys.derive(KEY, bytes(8))) is P.DropReason.UNAUTHENTICATED


def test_that_a_reflected_telemetry_datagram_is_refused_by_the_agent() -> None:
    telemetry = P.encode_datagram(P.Datagram(P.UdpType.TELEMETRY, 1, 100, 5, b"{}"), KEYS)
    assert refused(telemetry) is P.DropReason.MALFORMED  # not a type meant for the agent
    # and a host -> agent datagram never verifies as agent -> host, even relabelled
    wire = bytearray(P.encode_datagram(command(1), KEYS))
    wire[3] = P.UdpType.TELEMETRY
    assert refused(bytes(wire), accept=P.TO_HOST) is P.DropReason.UNAUTHENTICATED


def test_that_the_direction_keys_differ() -> None:
    assert len({KEYS.hello, KEYS.to_agent, KEYS.to_host}) == 3


@pytest.mark.parametrize(("datagram", "reason"), [
    (P.Datagram(P.UdpType.COMMAND, 7, 100, 1, b"\x02\x00"), P.DropReason.OUT_OF_RANGE),
    (P.Datagram(0x55, 7, 100, 1), P.DropReason.MALFORMED),
    (P.Datagram(P.UdpType.COMMAND, 7, 100, 1, b"\x01"), P.DropReason.MALFORMED),
    (P.Datagram(P.UdpType.HELLO, 7, 100, 1, b"\x01"), P.DropReason.MALFORMED),
    (P.Datagram(P.UdpType.SET_TRIM, 7, 100, 1, P.TRIM_STRUCT.pack(2, 1500, 1)), P.DropReason.OUT_OF_RANGE),
    (P.Datagram(P.UdpType.SET_TRIM, 7, 100, 1, P.TRIM_STRUCT.pack(0, 1299, 1)), P.DropReason.OUT_OF_RANGE),
    (P.Datagram(P.UdpType.SET_TRIM, 7, 100, 1, P.TRIM_STRUCT.pack(0, 1500, 0)), P.DropReason.OUT_OF_RANGE),
    (P.Datagram(P.UdpType.SET_TRIM, 7, 100, 1, b"\x00\xdc\x05"), P.DropReason.MALFORMED),
])
def test_that_authenticated_but_bad_datagrams_are_refused(datagram: P.Datagram, reason: P.DropReason) -> None:
    assert refused(P.encode_datagram(datagram, KEYS)) is reason


def test_that_the_replay_guard_wants_increasing_counters_per_sender_and_epoch() -> None:
    guard = P.ReplayGuard()
    assert guard.check(command(5)) is None
    assert guard.check(command(5)) is P.DropReason.REPLAYED
    assert guard.check(command(4)) is P.DropReason.REPLAYED
    assert guard.check(command(6)) is None
    assert guard.check(command(1, sender=8)) is None  # other senders are independent
    assert guard.check(command(1, epoch=101)) is None  # a newer epoch restarts the counter
    assert guard.check(command(7, epoch=100)) is P.DropReason.STALE


def test_that_a_sender_id_flood_keeps_the_replay_state_bounded() -> None:
    guard = P.ReplayGuard()
    assert guard.check(command(10, sender=1)) is None
    for sender in range(2, 40_000):  # each a new sender id with a newer epoch: all accepted, the oldest evicted
        guard.check(command(1, sender=sender, epoch=100 + sender))
    assert len(guard) == P.MAX_SENDERS and guard.evicted == 40_000 - 1 - P.MAX_SENDERS


def test_replay_after_a_sender_flood_evicts_the_victim_is_stale() -> None:
    """The attack: replay captured datagrams of 32+ old host processes (each its own sender id
    and an older epoch) to push the running host's replay state out, then replay that host's
    own last datagram. Eviction leaves a floor: no unknown sender at or below it gets in."""
    guard = P.ReplayGuard()
    victim = command(50, sender=7, epoch=1_000)
    assert guard.check(victim) is None
    for old in range(P.MAX_SENDERS):  # captured long ago: older epochs, other sender ids; the last
        assert guard.check(command(1, sender=1000 + old, epoch=900 + old)) is None  # pushes the victim out
    assert guard.evicted == 1 and guard.floor == 1_000
    assert guard.check(command(1, sender=2001, epoch=998)) is P.DropReason.STALE  # the rest of the flood too
    assert guard.check(victim) is P.DropReason.STALE
    assert guard.check(command(51, sender=7, epoch=1_000)) is P.DropReason.STALE  # the victim must restart
    assert guard.check(command(1, sender=7, epoch=1_001)) is None  # and then gets in, with its new epoch
    assert guard.check(command(1, sender=99, epoch=1_002)) is None  # as does any newer host


def test_that_malformed_datagrams_are_refused_without_a_crash() -> None:
    rng = random.Random(1)
    for _ in range(5000):
        blob = bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 80)))
        with pytest.raises(P.ProtocolError):
            P.decode_datagram(blob, KEYS, P.TO_AGENT)


def test_that_an_error_report_with_an_unknown_code_still_unpacks() -> None:
    report = P.ErrorReport.unpack(P.ErrorReport(0x42, 7).pack())
    assert report.name == "unknown_0x42" and report.seq == 7


@pytest.mark.parametrize("row", vectors("udp"), ids=lambda r: r[0])
def test_udp_vectors(row: list[str]) -> None:
    """``udp NAME KEY SESSION TYPE SENDER EPOCH COUNTER PAYLOAD WIRE``"""
    _, key, session, dtype, sender, epoch, counter, payload, wire = row
    keys = P.LinkKeys.derive(unhex(key), unhex(session))
    d = P.Datagram(int(dtype), int(sender), int(epoch), int(counter), unhex(payload))
    assert P.encode_datagram(d, keys) == unhex(wire)
    accept = P.TO_HOST if int(dtype) >= 0x80 else P.TO_AGENT
    assert P.decode_datagram(unhex(wire), keys, accept) == d


@pytest.mark.parametrize("row", vectors("udpkey"), ids=lambda r: r[0])
def test_udp_key_vectors(row: list[str]) -> None:
    """``udpkey KEY SESSION HELLO TO_AGENT TO_HOST``"""
    key, session, hello, to_agent, to_host = row
    keys = P.LinkKeys.derive(unhex(key), unhex(session))
    assert (keys.hello.hex(), keys.to_agent.hex(), keys.to_host.hex()) == (hello, to_agent, to_host)


@pytest.mark.parametrize("row", vectors("msg"), ids=lambda r: r[0])
def test_message_table_vectors(row: list[str]) -> None:
    mtype, direction, size = row
    spec = P.MESSAGES[P.MsgType(int(mtype))]
    assert (spec.direction, spec.size) == (direction, int(size))


@pytest.mark.parametrize("row", vectors("status"))
def test_status_vectors(row: list[str]) -> None:
    *fields, payload = row
    status = P.Status(*map(int, fields))
    assert status.pack() == unhex(payload) and P.Status.unpack(unhex(payload)) == status


@pytest.mark.parametrize("row", vectors("info"))
def test_info_vectors(row: list[str]) -> None:
    protocol, major, minor, patch, rn, rd, ln, ld, payload = row
    info = P.Info(int(protocol), int(major), int(minor), int(patch), (int(rn), int(ln)), (int(rd), int(ld)))
    assert info.pack() == unhex(payload) and P.Info.unpack(unhex(payload)) == info
    assert info.trims()["left"] == {"neutral_us": int(ln), "direction": int(ld)}


def test_that_the_servo_pulses_are_the_firmwares() -> None:
    """The pulse constants the twin, the agent and the firmware tests use are the ones
    ``tumble_config.h`` compiles into the firmware."""
    header = (VECTORS.parents[1] / "arduino" / "lib" / "tumbleproto" / "tumble_config.h").read_text()
    constants = {name: int(value) for name, value in re.findall(r"constexpr uint16_t (k\w+) = (\d+);", header)}
    assert (constants["kNeutralUs"], constants["kFullSpeedDeltaUs"]) == (P.NEUTRAL_US, P.FULL_SPEED_US)
    assert (constants["kNeutralMinUs"], constants["kNeutralMaxUs"]) == (P.NEUTRAL_MIN_US, P.NEUTRAL_MAX_US)
