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

import contextlib
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ELF = ROOT / "firmware" / "arduino" / "build" / "tumblebot.elf"
HARNESS = ROOT / "hil_tests" / "harness" / "build" / "tumble_sim"
PINS = {"right": 9, "left": 10}


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
        self.resets: list[float] = []
        self.chatter: list[str] = []  #: simavr's own messages (not events)
        self.width = {9: None, 10: None}  # type: dict[int, float | None]
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
            elif parts[0] == "@pulse":
                ev = PulseEvent(now, int(parts[1]), int(parts[2]), float(parts[3]))
                with self._lock:
                    self.events.append(ev)
                    self.width[ev.pin] = ev.width
            elif parts[0] == "@reset":
                with self._lock:
                    self.resets.append(now)
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

    def wait_for(self, right: float, left: float, timeout: float, tolerance: float = 10.0) -> float:
        """Seconds until both pins show the given widths (raises TimeoutError)."""
        start = time.monotonic()
        while time.monotonic() - start < timeout:
            r, lw = self.widths()
            if r is not None and lw is not None and abs(r - right) <= tolerance and abs(lw - left) <= tolerance:
                return time.monotonic() - start
            time.sleep(0.001)
        raise TimeoutError(f"pulses {self.widths()} did not reach ({right}, {left}) within {timeout} s")

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
