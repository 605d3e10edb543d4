"""Fixtures for the hardware-in-the-loop tests: the real firmware in simavr."""

from __future__ import annotations

import sys
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
        import time

        frames: list[P.Frame] = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            frames += self.decoder.feed(self.uno.port.read(256))
        self.received += frames
        return frames

    def wait_for(self, mtype: P.MsgType, timeout: float = WAIT) -> P.Frame:
        """The first frame of this type received so far or within ``timeout`` seconds."""
        import time

        end = time.monotonic() + timeout
        while True:
            for f in self.received:
                if f.type == mtype:
                    return f
            if time.monotonic() > end:
                raise TimeoutError(f"no {mtype.name} from the firmware within {timeout} s")
            self.read(0.05)

    def wait_ready(self, timeout: float = WAIT) -> P.Frame:
        import time

        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for f in self.read(0.05):
                if f.type == P.MsgType.READY:
                    self.epoch = f.epoch
                    return f
        raise TimeoutError(f"no READY from the firmware within {timeout} s")

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
        import time

        self.send(P.MsgType.GET_STATUS)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for f in self.read(0.02):
                if f.type == P.MsgType.STATUS:
                    return P.Status.unpack(f.payload)
        raise TimeoutError("no STATUS reply")


@pytest.fixture
def uno() -> Iterator[EmulatedUno]:
    with EmulatedUno() as emulated:
        yield emulated


@pytest.fixture
def link(uno: EmulatedUno) -> Link:
    link = Link(uno)
    link.wait_ready()
    return link
