"""The Python protocol against the shared vectors, and the UDP authentication rules."""

from __future__ import annotations

import os
import random
import struct
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
    with pytest.raises(P.ProtocolError) as info:
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


def command(counter: int, epoch: int = 100, sender: int = 7, speeds: tuple[int, int] = (1, -1)) -> P.Datagram:
    return P.Datagram(P.UdpType.COMMAND, sender, epoch, counter, struct.pack("<bb", *speeds))


def test_that_a_datagram_round_trips_with_its_key() -> None:
    d = command(1)
    assert P.decode_datagram(P.encode_datagram(d, KEY), KEY) == d


def test_that_a_forged_or_tampered_datagram_is_unauthenticated() -> None:
    wire = bytearray(P.encode_datagram(command(1), KEY))
    with pytest.raises(P.ProtocolError) as info:
        P.decode_datagram(bytes(wire), os.urandom(32))
    assert info.value.code is P.DropReason.UNAUTHENTICATED
    wire[21] ^= 0x01  # flip a payload bit
    with pytest.raises(P.ProtocolError) as info:
        P.decode_datagram(bytes(wire), KEY)
    assert info.value.code is P.DropReason.UNAUTHENTICATED


@pytest.mark.parametrize(("datagram", "reason"), [
    (command(1, speeds=(2, 0)), P.DropReason.OUT_OF_RANGE),
    (P.Datagram(0x55, 7, 100, 1), P.DropReason.OUT_OF_RANGE),
    (P.Datagram(P.UdpType.COMMAND, 7, 100, 1, b"\x01"), P.DropReason.OUT_OF_RANGE),
])
def test_that_authenticated_but_out_of_range_datagrams_are_refused(datagram: P.Datagram,
                                                                    reason: P.DropReason) -> None:
    with pytest.raises(P.ProtocolError) as info:
        P.decode_datagram(P.encode_datagram(datagram, KEY), KEY)
    assert info.value.code is reason


def test_that_the_replay_guard_wants_increasing_counters_per_sender_and_epoch() -> None:
    guard = P.ReplayGuard()
    assert guard.check(command(5)) is None
    assert guard.check(command(5)) is P.DropReason.REPLAYED
    assert guard.check(command(4)) is P.DropReason.REPLAYED
    assert guard.check(command(6)) is None
    assert guard.check(command(1, sender=8)) is None  # other senders are independent
    assert guard.check(command(1, epoch=101)) is None  # a newer epoch restarts the counter
    assert guard.check(command(7, epoch=100)) is P.DropReason.STALE


def test_that_malformed_datagrams_are_refused_without_a_crash() -> None:
    rng = random.Random(1)
    for _ in range(5000):
        blob = bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 80)))
        with pytest.raises(P.ProtocolError):
            P.decode_datagram(blob, KEY)
