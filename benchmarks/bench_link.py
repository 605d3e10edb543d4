"""Command latency through the robot link, on loopback, with the firmware in simavr.

Run: ``.venv/bin/python benchmarks/bench_link.py [--commands 1000]``

A host socket sends authenticated COMMAND datagrams (every 120 ms, so the agent's 10 Hz
rate limit never delays them) to the real agent code (run in this process so the serial
writes can be timestamped) which writes to the emulated Uno's pty; the harness reports
the new pulse widths measured on the pins. Reported, p50 and p99:

* datagram sent -> the SET_SPEEDS frame written to the serial line (the agent's share);
* datagram sent -> the new pulse width seen on the emulated pins (includes the UART at
  115 200 baud and waiting for the next 20 ms servo frame, so up to ~21 ms by design);
* the host falling silent: last datagram sent -> both pins neutral (the agent's 1 s host
  timer, then the same path; the HIL tests check the timer on a test clock, so that a
  busy machine cannot fail them, and leave its wall-clock figure to this benchmark).
"""

from __future__ import annotations

import argparse
import platform
import socket
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.host.emulator import EmulatedUno
from tumblebot.pi_agent import protocol as P
from tumblebot.pi_agent.agent import Agent, AgentConfig, open_serial

KEY = bytes(range(32))


class TimedPort:
    """Wraps the agent's serial port and timestamps every SET_SPEEDS it writes."""

    def __init__(self, port: Any, log: list[tuple[float, bytes]]) -> None:
        self._port, self._log = port, log

    def write(self, data: bytes) -> int:
        n = int(self._port.write(data))
        self._log.append((time.monotonic(), data))
        return n

    def __getattr__(self, name: str) -> Any:
        return getattr(self._port, name)


def speeds_in(data: bytes) -> tuple[int, int] | None:
    """The (right, left) of a SET_SPEEDS frame in one serial write, else None."""
    for frame in P.FrameDecoder().feed(data):
        if frame.type == P.MsgType.SET_SPEEDS:
            right, left = P.unpack_speeds(frame.payload)
            return right, left
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--commands", type=int, default=1000)
    parser.add_argument("--silences", type=int, default=5, help="host-silence stops to time")
    args = parser.parse_args()
    writes: list[tuple[float, bytes]] = []
    with EmulatedUno() as uno, tempfile.TemporaryDirectory() as tmp:
        config = AgentConfig(serial_port=uno.pty, bind_address="127.0.0.1", bind_port=0,
                             allowed_host="127.0.0.1", key_file=str(Path(tmp) / "unused"))
        agent = Agent(config, KEY, serial_factory=lambda url, baud: TimedPort(open_serial(url, baud), writes))
        stop = threading.Event()
        thread = threading.Thread(target=agent.run, kwargs={"stop": stop.is_set}, daemon=True)
        thread.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        while not agent.link.ready:
            time.sleep(0.05)
        epoch, to_serial, to_pulse = int(time.time()), [], []
        keys = P.LinkKeys.derive(KEY, agent.session)  # in-process: the session needs no HELLO here
        states = [((1, 1), (2000.0, 1000.0)), ((0, 0), (1500.0, 1500.0))]
        for i in range(args.commands):
            (right, left), (w_right, w_left) = states[i % 2]
            wire = P.encode_datagram(P.Datagram(P.UdpType.COMMAND, 7, epoch, i + 1, P.command_payload(right, left)),
                                     keys)
            mark = len(writes)
            sent = time.monotonic()
            sock.sendto(wire, agent.address)
            uno.wait_for(w_right, w_left, timeout=1.0, tolerance=1.0)
            to_pulse.append(time.monotonic() - sent)
            written = [t for t, data in writes[mark:] if speeds_in(data) == (right, left)]
            if written:
                to_serial.append(written[0] - sent)
            time.sleep(max(0.0, 0.12 - (time.monotonic() - sent)))
        to_stop = []
        for j in range(args.silences):
            counter = args.commands + j + 1
            wire = P.encode_datagram(P.Datagram(P.UdpType.COMMAND, 7, epoch, counter, P.command_payload(1, 1)), keys)
            time.sleep(0.2)  # past the rate limit's slot
            sent = time.monotonic()
            sock.sendto(wire, agent.address)
            uno.wait_for(2000.0, 1000.0, tolerance=1.0)
            to_stop.append(uno.wait_for(1500.0, 1500.0, tolerance=1.0).wall - sent)
        stop.set()
        thread.join(timeout=2)
    print(f"robot link latency, {time.strftime('%Y-%m-%d')}, {platform.machine()}, {args.commands} commands, "
          "loopback, firmware in simavr (paced to real time)")
    for name, values in (("datagram -> serial frame", to_serial), ("datagram -> pulse on the pins", to_pulse),
                         ("host silent -> pins neutral", to_stop)):
        if not values:
            continue
        ms = 1e3 * np.array(values)
        print(f"  {name:<30} p50 {np.percentile(ms, 50):7.2f} ms   p99 {np.percentile(ms, 99):7.2f} ms   (n={len(ms)})")


if __name__ == "__main__":
    main()
