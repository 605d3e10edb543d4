"""Fixtures for the hardware-in-the-loop tests: the real firmware in simavr."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from tumblebot.host.emulator import WAIT, EmulatedUno
from tumblebot.pi_agent import protocol as P


class Link:
    """The agent's view of the serial line: send frames, read frames, learn the epoch."""

    def __init__(self, uno: EmulatedUno) -> None:
        self.uno = uno
        self.decoder = P.FrameDecoder()
        self.epoch: int | None = None
        self.seq = 0
        self.received: list[P.Frame] = []

    def read(self, seconds: float) -> list[P.Frame]:
        frames: list[P.Frame] = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            frames += self.decoder.feed(self.uno.port.read(256))
        self.received += frames
        return frames

    def _first(self, mtype: P.MsgType, after: int, timeout: float) -> P.Frame:
        """The first frame of this type among those received after the first ``after``,
        reading for up to ``timeout`` seconds."""
        end = time.monotonic() + timeout
        while True:
            for f in self.received[after:]:
                if f.type == mtype:
                    return f
            after = len(self.received)
            if time.monotonic() > end:
                raise TimeoutError(f"no {mtype.name} from the firmware within {timeout} s")
            self.read(0.02)

    def wait_for(self, mtype: P.MsgType, timeout: float = WAIT) -> P.Frame:
        """The first frame of this type received so far or within ``timeout`` seconds."""
        return self._first(mtype, 0, timeout)

    def wait_ready(self, timeout: float = WAIT) -> P.Frame:
        """The next READY (a boot), whose epoch the link then uses."""
        ready = self._first(P.MsgType.READY, len(self.received), timeout)
        self.epoch = ready.epoch
        return ready

    def send(self, mtype: P.MsgType, payload: bytes = b"", seq: int | None = None, epoch: int | None = None) -> int:
        if seq is None:
            self.seq = (self.seq + 1) & 0xFFFF
            seq = self.seq
        chosen = self.epoch if epoch is None else epoch
        assert chosen is not None
        frame = P.Frame(chosen, seq, mtype, payload)
        self.uno.write(b"\x00" + P.encode_frame(frame))  # leading delimiter: resynchronise after noise
        return seq

    def speeds(self, right: int, left: int) -> int:
        return self.send(P.MsgType.SET_SPEEDS, P.set_speeds_payload(right, left))

    def status(self, timeout: float = WAIT) -> P.Status:
        asked = len(self.received)
        self.send(P.MsgType.GET_STATUS)
        return P.Status.unpack(self._first(P.MsgType.STATUS, asked, timeout).payload)


@pytest.fixture
def uno() -> Iterator[EmulatedUno]:
    with EmulatedUno() as emulated:
        yield emulated


@pytest.fixture
def link(uno: EmulatedUno) -> Link:
    link = Link(uno)
    link.wait_ready()
    return link
