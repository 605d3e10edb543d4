"""The whole robot link: UDP client -> the real agent (a process) -> pty -> the real
firmware in simavr -> measured servo pulses."""

from __future__ import annotations

import json
import os
import random
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tumblebot.pi_agent import protocol as P

from emulator import EmulatedUno

KEY = bytes(range(32))
NEUTRAL = 1500.5


class Host:
    """What the host controller does: authenticated datagrams with a rising counter."""

    def __init__(self, port: int, key: bytes = KEY, sender: int = 7) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(1.0)
        self.addr = ("127.0.0.1", port)
        self.key, self.sender = key, sender
        self.epoch = int(time.time())
        self.counter = 0

    def datagram(self, dtype: int, payload: bytes = b"", counter: int | None = None, key: bytes | None = None) -> bytes:
        if counter is None:
            self.counter += 1
            counter = self.counter
        return P.encode_datagram(P.Datagram(dtype, self.sender, self.epoch, counter, payload), key or self.key)

    def send(self, wire: bytes) -> None:
        self.sock.sendto(wire, self.addr)

    def command(self, right: int, left: int) -> bytes:
        wire = self.datagram(P.UdpType.COMMAND, struct.pack("<bb", right, left))
        self.send(wire)
        return wire

    def telemetry(self) -> dict:
        nonce = random.getrandbits(32)
        self.send(self.datagram(P.UdpType.TELEMETRY_REQUEST, struct.pack("<I", nonce)))
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            data, _ = self.sock.recvfrom(2048)
            d = P.decode_datagram(data, self.key)
            body = json.loads(d.payload)
            if body["nonce"] == nonce:
                return body
        raise TimeoutError("no telemetry")


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.fixture
def chain(tmp_path: Path) -> Iterator[tuple[EmulatedUno, Host, subprocess.Popen, Path]]:
    uno = EmulatedUno()
    device = tmp_path / "ttyACM0"  # a stable name, as udev gives a real Uno
    device.symlink_to(uno.pty)
    key_file = tmp_path / "agent.key"
    key_file.write_bytes(KEY)
    key_file.chmod(0o600)
    port = free_udp_port()
    config = tmp_path / "agent.toml"
    config.write_text(f'serial_port = "{device}"\nbind_address = "127.0.0.1"\nbind_port = {port}\n'
                      f'allowed_host = "127.0.0.1"\nkey_file = "{key_file}"\n')
    agent = subprocess.Popen([sys.executable, "-m", "tumblebot.pi_agent.agent", "--config", str(config)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    host = Host(port)
    try:
        deadline = time.monotonic() + 10
        while True:  # the agent is up and has heard READY
            try:
                if host.telemetry()["serial_connected"]:
                    break
            except (TimeoutError, OSError):
                pass
            assert time.monotonic() < deadline, "agent never connected"
        yield uno, host, agent, device
    finally:
        agent.terminate()
        agent.wait(timeout=5)
        uno.close()


def test_that_a_command_from_the_host_moves_the_servos_and_then_keeps_them_moving(chain) -> None:  # type: ignore[no-untyped-def]
    uno, host, _, _ = chain
    host.command(1, 1)
    uno.wait_for(2000.5, 1000.5, timeout=0.2, tolerance=1.0)
    for _ in range(8):  # the agent's 10 Hz keepalive holds the firmware's 250 ms watchdog off
        time.sleep(0.1)
        host.command(1, 1)
        assert uno.widths()[0] == pytest.approx(2000.5, abs=1)


def test_that_forged_replayed_and_foreign_datagrams_never_act(chain) -> None:  # type: ignore[no-untyped-def]
    uno, host, _, _ = chain
    host.send(host.datagram(P.UdpType.COMMAND, struct.pack("<bb", 1, 1), key=os.urandom(32)))  # forged
    time.sleep(0.2)
    assert uno.widths()[0] == pytest.approx(NEUTRAL, abs=1)
    wire = host.command(-1, -1)
    uno.wait_for(1000.5, 2000.5, timeout=0.2, tolerance=1.0)
    host.command(0, 0)
    uno.wait_for(NEUTRAL, NEUTRAL, timeout=0.3, tolerance=1.0)
    host.send(wire)  # replay of the (-1, -1) command
    time.sleep(0.25)
    assert uno.widths()[0] == pytest.approx(NEUTRAL, abs=1)
    telemetry = host.telemetry()
    drops = telemetry["drops"]
    assert drops["unauthenticated"] == 1 and drops["replayed"] == 1
    assert telemetry["link_loss"] == 0.0
    assert telemetry["rtt_ms"]["median"] < 50
    assert telemetry["firmware_status"]["flags"] & 1  # armed


def test_that_too_frequent_commands_act_at_10_hz_with_the_latest_winning(chain) -> None:  # type: ignore[no-untyped-def]
    uno, host, _, _ = chain
    host.command(1, 1)
    uno.wait_for(2000.5, 1000.5, timeout=0.2, tolerance=1.0)
    start = time.monotonic()
    host.command(-1, -1)  # within the same 100 ms slot ...
    host.command(0, 1)  # ... superseded by this one
    uno.wait_for(NEUTRAL, 1000.5, timeout=0.3, tolerance=1.0)
    assert time.monotonic() - start >= 0.05  # waited for its slot
    assert not any(abs(e.width - 1000.5) < 1 and e.pin == 9 for e in uno.events_since(start))  # (-1,-1) never acted
    assert host.telemetry()["drops"]["rate_limited"] == 1


def test_that_losing_the_host_for_a_second_stops_the_robot(chain) -> None:  # type: ignore[no-untyped-def]
    uno, host, _, _ = chain
    host.command(1, 1)
    uno.wait_for(2000.5, 1000.5, timeout=0.2, tolerance=1.0)
    start = time.monotonic()
    waited = start + uno.wait_for(NEUTRAL, NEUTRAL, timeout=2.0, tolerance=1.0) - start
    assert 0.9 < waited < 1.3


def test_that_a_vanished_serial_device_is_detected_and_the_agent_reconnects(chain) -> None:  # type: ignore[no-untyped-def]
    uno, host, _, device = chain
    uno.close()  # the USB cable is pulled: the pty disappears
    deadline = time.monotonic() + 1.5
    while host.telemetry()["serial_connected"]:
        assert time.monotonic() < deadline, "loss not detected within about 1 s"
        time.sleep(0.05)
    fresh = EmulatedUno()  # plugged back in (a new boot)
    try:
        device.unlink()
        device.symlink_to(fresh.pty)
        deadline = time.monotonic() + 10
        while not host.telemetry()["serial_connected"]:
            assert time.monotonic() < deadline, "agent did not reconnect"
            time.sleep(0.1)
        host.command(1, 0)
        fresh.wait_for(2000.5, NEUTRAL, timeout=0.5, tolerance=1.0)
    finally:
        fresh.close()


@pytest.mark.slow
def test_that_100000_random_and_mutated_datagrams_neither_crash_nor_actuate(chain) -> None:  # type: ignore[no-untyped-def]
    uno, host, agent, _ = chain
    rng = random.Random(7)
    start = time.monotonic()
    template = host.datagram(P.UdpType.COMMAND, struct.pack("<bb", 1, 1), counter=10**9)
    for i in range(100_000):
        if i % 2:
            wire = bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 64)))
        else:
            mutated = bytearray(template)
            mutated[rng.randrange(len(mutated))] ^= 1 << rng.randrange(8)
            wire = bytes(mutated)
        host.send(wire)
        if i % 200 == 0:
            time.sleep(0.01)  # let the agent keep up rather than the kernel dropping them
    time.sleep(0.3)
    assert agent.poll() is None, agent.stderr.read() if agent.stderr else ""
    assert {round(e.width) for e in uno.events_since(start)} <= {1500, 1501}
    telemetry = host.telemetry()
    assert telemetry["command"] == [0, 0]
    assert sum(telemetry["drops"].values()) > 90_000  # counted, give or take kernel buffer overflows
