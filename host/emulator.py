"""The firmware ELF running in simavr (``hil_tests/harness/tumble_sim``), seen from Python.

The one driver of the emulated Uno: the HIL tests, the digital twin and the link
benchmarks all import it from here. It needs a source checkout (the firmware and the
harness are built from it with Debian's avr-gcc and simavr) and pyserial (the ``agent``
extra).

:class:`EmulatedUno` starts the harness, opens its pseudo-terminal with pyserial exactly as
the agent opens ``/dev/ttyACM0`` on a Pi (before the AVR starts, since pyserial's
``open()`` discards pending input), and collects the servo pulse widths the harness
measures from the pins.
"""

from __future__ import annotations

import bisect
import contextlib
import math
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ELF = ROOT / "firmware" / "arduino" / "build" / "tumblebot.elf"
HARNESS = ROOT / "hil_tests" / "harness" / "build" / "tumble_sim"
PINS = {"right": 9, "left": 10}
WAIT = 10.0  #: s: the default bound on waiting for an event that takes milliseconds (a bound, not a measure)


def build() -> None:
    """Build the firmware and the harness (no-ops when up to date)."""
    subprocess.run(["make", "-s", "-C", str(ROOT / "firmware" / "arduino"), "all"], check=True, capture_output=True)
    subprocess.run(["make", "-s", "-C", str(ROOT / "hil_tests" / "harness")], check=True, capture_output=True)


@dataclass(frozen=True)
class PulseEvent:
    wall: float  #: time.monotonic() when the harness reported it
    sim_us: int  #: simulated microseconds
    pin: int
    width: float  #: microseconds


class EmulatedUno:
    def __init__(self, paced: bool = True, baud: int = 115_200) -> None:
        import serial  # the agent extra

        build()
        args = [str(HARNESS), str(ELF)] + ([] if paced else ["--unpaced"])
        self.proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, bufsize=1)
        assert self.proc.stdout is not None
        self.pty = ""
        for line in self.proc.stdout:
            if line.startswith("@pty "):
                self.pty = line.split()[1]
                break
        if not self.pty:
            raise RuntimeError("tumble_sim did not report its pty")
        self.port = serial.serial_for_url(self.pty, baudrate=baud, timeout=0.05, write_timeout=5)
        self.sim_us = 0  #: latest simulated time reported by the harness
        self._byte_time_us = 11e6 / baud * 1.25  # simavr counts 11 bits per 8N1 byte
        self._line_free_us = 0.0
        self.events: list[PulseEvent] = []
        self.resets: list[float] = []  #: time.monotonic() of each reset the harness reported
        self.reset_us: list[int] = []  #: and its simulated time
        self.chatter: list[str] = []  #: simavr's own messages (not events)
        self.width = {9: None, 10: None}  # type: dict[int, float | None]
        self.written = 0  #: bytes :meth:`write` has put on the line
        self._handed: list[tuple[int, int]] = []  # (simulated us, bytes handed to the AVR's UART so far)
        self._reset_marks: list[int] = []  # len(self.events) at each reset
        self._lock = threading.Lock()
        self._started = threading.Event()
        self._thread = threading.Thread(target=self._read_events, daemon=True)
        self._thread.start()
        self._command("start")
        if not self._started.wait(10):
            raise RuntimeError("tumble_sim did not start")

    def write(self, data: bytes, chunk: int = 8) -> None:
        """Write to the UART no faster than the emulated line can take it.

        simavr 1.6's pty bridge stalls for good once too many bytes wait in it (found
        here: 2 kB of noise in one write(), or a steady stream faster than the emulator
        runs, and the firmware never hears another byte). So bytes go in small chunks,
        each only when simulated time has caught up with the line time of everything
        written before (11 bits per byte at the baud rate, +25 %): the emulated UART's
        receive FIFO never fills, so simavr never has to signal XOFF.
        """
        for i in range(0, len(data), chunk):
            piece = data[i:i + chunk]
            deadline = time.monotonic() + 10
            while self.sim_us < self._line_free_us:
                if time.monotonic() > deadline:
                    raise TimeoutError("the emulator stopped advancing")
                time.sleep(0.0005)
            self.port.write(piece)
            self.written += len(piece)
            self._line_free_us = max(self._line_free_us, self.sim_us) + len(piece) * self._byte_time_us

    def _command(self, text: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(text + "\n")
        self.proc.stdin.flush()

    def _read_events(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            parts = line.split()
            if not parts or not parts[0].startswith("@"):
                self.chatter.append(line.rstrip())
                continue
            now = time.monotonic()
            if parts[0] == "@started":
                self._started.set()
            elif parts[0] == "@time":
                self.sim_us = int(parts[1])
            elif parts[0] == "@rx":
                with self._lock:
                    total = (self._handed[-1][1] if self._handed else 0) + int(parts[2])
                    self._handed.append((int(parts[1]), total))
            elif parts[0] == "@pulse":
                ev = PulseEvent(now, int(parts[1]), int(parts[2]), float(parts[3]))
                with self._lock:
                    self.events.append(ev)
                    self.width[ev.pin] = ev.width
            elif parts[0] == "@reset":
                with self._lock:
                    self.resets.append(now)
                    self.reset_us.append(int(parts[1]))
                    self._reset_marks.append(len(self.events))
                    self.width = {9: None, 10: None}

    def reset(self) -> None:
        """Reset the AVR (as pressing the reset button would)."""
        self._command("reset")

    def widths(self) -> tuple[float | None, float | None]:
        with self._lock:
            return self.width[9], self.width[10]

    def events_since(self, t: float) -> list[PulseEvent]:
        with self._lock:
            return [e for e in self.events if e.wall >= t]

    def wait_for(self, right: float, left: float, timeout: float = WAIT, tolerance: float = 10.0) -> PulseEvent:
        """The pulse event at which both pins first show the given widths (the last event,
        if they already do); ``timeout`` bounds the wait and is not a measurement: time
        what the firmware does with the event's ``sim_us``. Raises TimeoutError."""

        def matches(state: dict[int, float | None]) -> bool:
            r, lw = state[9], state[10]
            return r is not None and lw is not None and abs(r - right) <= tolerance and abs(lw - left) <= tolerance

        with self._lock:
            state, seen, resets = dict(self.width), len(self.events), len(self._reset_marks)
            if matches(state) and self.events:
                return self.events[-1]
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                new, marks = self.events[seen:], self._reset_marks[resets:]
                resets = len(self._reset_marks)
            for ev in new:
                if marks and marks[0] <= seen:  # a reset came before this event: the pins went quiet
                    marks = [m for m in marks if m > seen]
                    state = {9: None, 10: None}
                seen += 1
                state[ev.pin] = ev.width
                if matches(state):
                    return ev
            if marks:
                state = {9: None, 10: None}
            time.sleep(0.001)
        raise TimeoutError(f"pulses {self.widths()} did not reach ({right}, {left}) within {timeout} s")

    def handed_us(self, count: int | None = None, timeout: float = WAIT) -> int:
        """Simulated microseconds at which the AVR's UART had been handed the first
        ``count`` bytes :meth:`write` put on the line (default: all of them so far)."""
        want = self.written if count is None else count
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                if self._handed and self._handed[-1][1] >= want:
                    return self._handed[bisect.bisect_left(self._handed, want, key=lambda h: h[1])][0]
            time.sleep(0.001)
        raise TimeoutError(f"the emulator took only part of the {want} bytes written within {timeout} s")

    def wait_until_us(self, sim_us: float, timeout: float = WAIT) -> None:
        """Wait until the emulated clock reaches ``sim_us`` (a pause in simulated time)."""
        deadline = time.monotonic() + timeout
        while self.sim_us < sim_us:
            if time.monotonic() > deadline:
                raise TimeoutError(f"the emulator stopped at {self.sim_us} us, short of {math.ceil(sim_us)} us")
            time.sleep(0.001)

    def close(self) -> None:
        with contextlib.suppress(BrokenPipeError, ValueError):
            self._command("quit")
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.port.close()

    def __enter__(self) -> EmulatedUno:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
