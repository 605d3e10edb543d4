"""Fixtures of the host tests: a Pi agent process, with the real firmware in simavr on its
serial port, or with nothing there (pyserial's loop://: an unplugged Arduino)."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tumblebot.host.emulator import EmulatedUno
from tumblebot.host.link import AgentClient, free_port, load_host_key, new_key


def _agent(tmp_path: Path, serial_port: str) -> Iterator[tuple[str, Path]]:
    key = tmp_path / "agent.key"
    new_key(key)
    port = free_port()
    config = tmp_path / "agent.toml"
    config.write_text(f'serial_port = "{serial_port}"\nbind_address = "127.0.0.1"\nbind_port = {port}\n'
                      f'allowed_host = "127.0.0.1"\nkey_file = "{key}"\n')
    proc = subprocess.Popen([sys.executable, "-m", "tumblebot.pi_agent.agent", "--config", str(config)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    client = AgentClient(("127.0.0.1", port), load_host_key(key))
    deadline = time.monotonic() + 30
    while not client.poll():
        assert time.monotonic() < deadline, "agent did not start"
        client.request_telemetry()
        time.sleep(0.2)
    client.close()
    try:
        yield f"127.0.0.1:{port}", key
    finally:
        proc.terminate()
        proc.wait(timeout=5)


@pytest.fixture
def agent(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """An agent process whose Arduino is the real firmware in simavr."""
    with EmulatedUno() as uno:
        yield from _agent(tmp_path, uno.pty)


@pytest.fixture
def unplugged_agent(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """An agent process whose serial port has no Arduino behind it (its USB cable is out)."""
    yield from _agent(tmp_path, "loop://")




@pytest.fixture
def uno_and_agent(tmp_path: Path) -> Iterator[tuple[EmulatedUno, str, Path]]:
    """The firmware in simavr (to reset it, or read its pins) and an agent process on it."""
    with EmulatedUno() as uno:
        for address, key in _agent(tmp_path, uno.pty):
            yield uno, address, key
