"""The real firmware ELF in simavr, driven over its UART exactly as the Pi agent does."""

from __future__ import annotations

import random
import struct
import time

import pytest

from tumblebot.host.emulator import WAIT, EmulatedUno
from tumblebot.pi_agent import protocol as P

from conftest import Link

pytestmark = pytest.mark.hil

NEUTRAL, FULL = float(P.NEUTRAL_US), float(P.FULL_SPEED_US)
FULL_FWD_RIGHT, FULL_FWD_LEFT = NEUTRAL + FULL, NEUTRAL - FULL  # the left servo is mirrored


def test_that_set_speeds_reaches_the_pins_within_50_ms(uno: EmulatedUno, link: Link) -> None:
    """Timed in simulated time, from the frame handed to the AVR's UART to the new pulse
    measured on the pins, so a busy machine cannot fail it (benchmarks/bench_link.py times
    the whole path on the wall clock)."""
    for right, left in ((1, 1), (-1, 0), (0, -1), (1, -1)):
        link.speeds(right, left)
        handed = uno.handed_us()
        reached = uno.wait_for(NEUTRAL + FULL * right, NEUTRAL - FULL * left, tolerance=1.0)
        assert 0 < reached.sim_us - handed < 50_000, f"({right}, {left}) took {(reached.sim_us - handed) / 1e3:.1f} ms"
        uno.wait_until_us(reached.sim_us + 100_000)


def test_that_each_pulse_is_the_commanded_width_to_the_timer_tick(uno: EmulatedUno, link: Link) -> None:
    """Fast PWM holds a pin high for OCR1x + 1 timer ticks (0.5 µs each); the firmware once
    left out the - 1 and made every pulse a tick too long: 1500.5 µs for neutral."""
    assert uno.widths() == pytest.approx((NEUTRAL, NEUTRAL), abs=0.25)  # at boot
    for right, left in ((1, 1), (-1, 0), (0, -1)):
        link.speeds(right, left)
        reached = uno.wait_for(NEUTRAL + FULL * right, NEUTRAL - FULL * left, tolerance=1.0)
        uno.wait_until_us(reached.sim_us + 60_000)  # three frames on, within the watchdog's 250 ms
        assert uno.widths() == pytest.approx((NEUTRAL + FULL * right, NEUTRAL - FULL * left), abs=0.25)


def test_that_the_watchdog_returns_both_servos_to_neutral_within_300_ms_every_time(uno: EmulatedUno,
                                                                                  link: Link) -> None:
    """The keepalive is paced and the watchdog timed in simulated time, as the firmware
    sees them; a gap the test itself could not keep under 250 ms (a starved test
    process) is an honest extra trip, counted."""
    rounds, late_gaps = 3, 0
    for _ in range(rounds):
        link.speeds(1, 1)
        last = uno.handed_us()
        uno.wait_for(FULL_FWD_RIGHT, FULL_FWD_LEFT, tolerance=1.0)
        for _ in range(3):  # keep the link alive for a while, as the agent does at 10 Hz
            uno.wait_until_us(last + 100_000)
            link.speeds(1, 1)
            handed = uno.handed_us()
            if handed - last >= 250_000:
                late_gaps += 1
                uno.wait_for(FULL_FWD_RIGHT, FULL_FWD_LEFT, tolerance=1.0)  # re-armed after the extra trip
            last = handed
        neutral = uno.wait_for(NEUTRAL, NEUTRAL, tolerance=10.0)
        assert 250_000 <= neutral.sim_us - last < 300_000, f"neutral {(neutral.sim_us - last) / 1e3:.1f} ms after"
    assert link.status().watchdog_trips == rounds + late_gaps


def test_that_the_servos_stay_neutral_at_boot_until_a_valid_command_after_ready(uno: EmulatedUno) -> None:
    link = Link(uno)
    ready = link.wait_ready()
    assert ready.payload[0] == P.PROTOCOL_VERSION
    link.send(P.MsgType.SET_SPEEDS, P.set_speeds_payload(1, 1), epoch=(ready.epoch + 1) & 0xFFFF)  # stale epoch
    uno.wait_until_us(uno.handed_us() + 100_000)  # five servo frames after the firmware had it
    assert uno.widths() == pytest.approx((NEUTRAL, NEUTRAL), abs=1)
    error = link.wait_for(P.MsgType.ERROR)
    assert error.payload[0] == P.ErrorCode.STALE_EPOCH
    link.speeds(1, 1)
    uno.wait_for(FULL_FWD_RIGHT, FULL_FWD_LEFT, tolerance=1.0)


def test_that_a_reset_mid_run_is_neutral_until_a_new_valid_command(uno: EmulatedUno, link: Link) -> None:
    link.speeds(1, 1)
    uno.wait_for(FULL_FWD_RIGHT, FULL_FWD_LEFT, tolerance=1.0)
    old_epoch = link.epoch
    uno.reset()
    ready = link.wait_ready()
    assert ready.epoch != old_epoch  # the boot epoch changed (EEPROM boot counter)
    uno.wait_for(NEUTRAL, NEUTRAL, tolerance=1.0)
    link.send(P.MsgType.SET_SPEEDS, P.set_speeds_payload(1, 1), epoch=old_epoch)  # a command from before the reset
    uno.wait_until_us(uno.handed_us() + 100_000)  # five servo frames after the firmware had it
    assert uno.widths() == pytest.approx((NEUTRAL, NEUTRAL), abs=1)
    link.speeds(-1, -1)
    uno.wait_for(NEUTRAL - FULL, NEUTRAL + FULL, tolerance=1.0)


def test_that_the_emulated_clock_neither_jumps_nor_freezes_across_a_reset(uno: EmulatedUno, link: Link) -> None:
    """A paced emulator's clock never runs ahead of the wall clock (a starved one only
    falls behind), so the reset's own timestamp bounds a jump whatever the load."""
    uno.wait_until_us(2_000_000)  # run a while first: a clock that counted these cycles twice would jump 2 s
    before_us, wall = uno.sim_us, time.monotonic()
    uno.reset()
    deadline = time.monotonic() + WAIT
    while not uno.resets:
        assert time.monotonic() < deadline, "no reset reported"
        time.sleep(0.01)
    reset_us, reset_wall = uno.reset_us[0], uno.resets[0]
    assert 0 <= reset_us - before_us < 1e6 * (reset_wall - wall) + 200_000, (before_us, reset_us)
    link.wait_ready()
    assert uno.sim_us > reset_us  # and it runs on


def test_that_trims_persist_in_eeprom_across_a_reset(uno: EmulatedUno, link: Link) -> None:
    link.send(P.MsgType.SET_TRIM, struct.pack("<BHb", 0, 1520, -1))  # right: neutral 1520 us, reversed
    uno.wait_until_us(uno.handed_us() + 100_000)  # the EEPROM write takes 3.3 ms a byte
    uno.reset()
    link.wait_ready()
    uno.wait_for(1520.0, NEUTRAL, tolerance=1.0)  # the stored neutral, at boot
    link.speeds(1, 0)
    uno.wait_for(1020.0, NEUTRAL, tolerance=1.0)  # forward is now the short pulse


class FirmwareModel:
    """What the firmware should count for a byte stream (its rules, in Python)."""

    def __init__(self, epoch: int, last_seq: int) -> None:
        self.decoder = P.FrameDecoder()
        self.epoch, self.last_seq = epoch, last_seq
        self.ok = self.other = 0
        self.actuating: list[P.Frame] = []

    def feed(self, data: bytes) -> None:
        for f in self.decoder.feed(data):
            if f.type >= 0x80 or f.epoch != self.epoch or not P.newer(f.seq, self.last_seq):
                self.other += 1
                continue
            self.ok += 1
            self.last_seq = f.seq
            if f.type == P.MsgType.SET_SPEEDS:
                self.actuating.append(f)

    @property
    def crc(self) -> int:
        return self.decoder.errors[P.ErrorCode.BAD_CRC]

    @property
    def refused(self) -> int:
        return sum(n for code, n in self.decoder.errors.items() if code != P.ErrorCode.BAD_CRC) + self.other


@pytest.mark.slow
def test_that_noise_and_mutated_frames_never_actuate_and_are_all_counted() -> None:
    with EmulatedUno(paced=False) as uno:
        link = Link(uno)
        link.wait_ready()
        link.speeds(1, -1)
        uno.wait_for(FULL_FWD_RIGHT, FULL_FWD_RIGHT, tolerance=1.0)
        before = link.status()
        assert link.epoch is not None
        model = FirmwareModel(link.epoch, link.seq)
        start = time.monotonic()
        rng = random.Random(2024)
        chunk = 256
        noise_bytes = 1_000_000
        for _ in range(noise_bytes // chunk):
            data = bytes(rng.getrandbits(8) for _ in range(chunk))
            model.feed(data)
            uno.write(data)
            link.read(0)  # drain replies so the firmware never blocks on a full TX buffer
        flush = b"\x00"
        model.feed(flush)
        uno.write(flush)
        for i in range(10_000):
            seq = (link.seq + 1 + i) & 0xFFFF
            wire = bytearray(P.encode_frame(P.Frame(link.epoch, seq, P.MsgType.SET_SPEEDS,
                                                     P.set_speeds_payload(1, 1))))
            wire[rng.randrange(len(wire) - 1)] ^= 1 << rng.randrange(8)
            data = bytes(wire) + b"\x00"  # resynchronise if the flip hid a delimiter
            model.feed(data)
            uno.write(data)
            if i % 20 == 0:
                link.read(0)
        link.seq = (link.seq + 10_000) & 0xFFFF
        link.read(0.5)
        after = link.status(timeout=5.0)
        assert model.actuating == []
        widths = {round(e.width) for e in uno.events_since(start)}
        assert widths <= {NEUTRAL, NEUTRAL + FULL, NEUTRAL - FULL}, widths
        assert after.crc_errors - before.crc_errors == model.crc
        assert after.other_drops - before.other_drops == model.refused
        assert after.frames_ok - before.frames_ok == 1  # only the GET_STATUS itself
        assert uno.resets == []  # the AVR watchdog never fired
        assert not any(f.type == P.MsgType.READY for f in link.received[1:])
