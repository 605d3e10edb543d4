"""The agent's configuration and key file: bad input is one clear error."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tumblebot.pi_agent.agent import AgentConfig, AgentError, load_key


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_that_a_valid_config_loads(tmp_path: Path) -> None:
    cfg = AgentConfig.load(write(tmp_path / "a.toml", 'serial_port = "loop://"\nbind_port = 4000\n'))
    assert cfg.serial_port == "loop://" and cfg.bind_port == 4000 and cfg.baud == 115200


@pytest.mark.parametrize(("text", "message"), [
    ("serial_port = ", "not valid TOML"),
    ('colour = "red"\n', "unknown keys colour"),
    ('bind_port = "47800"\n', "bind_port must be a int"),
    ("bind_port = 70000\n", "not a UDP port"),
    ('allowed_host = "example.org"\n', "must be an IPv4 address"),
])
def test_that_bad_configs_are_refused(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(AgentError, match=message):
        AgentConfig.load(write(tmp_path / "a.toml", text))


def test_that_keys_must_be_32_bytes_and_private(tmp_path: Path) -> None:
    key = tmp_path / "k"
    key.write_bytes(bytes(range(32)))
    key.chmod(0o644)
    with pytest.raises(AgentError, match="accessible by group or others"):
        load_key(key)
    key.chmod(0o600)
    assert load_key(key) == bytes(range(32))
    key.write_bytes(bytes(range(31)))
    with pytest.raises(AgentError, match="exactly 32 bytes"):
        load_key(key)


@pytest.mark.parametrize("data", [bytes(32), b"\xff" * 32, b"ab" * 16, bytes(range(8)) * 4])
def test_that_an_all_zero_or_repeated_key_is_refused(tmp_path: Path, data: bytes) -> None:
    key = tmp_path / "k"
    key.write_bytes(data)
    key.chmod(0o600)
    with pytest.raises(AgentError, match=r"is not a random key .* head -c 32 /dev/urandom"):
        load_key(key)


def test_that_a_fifo_key_file_is_refused_without_hanging(tmp_path: Path) -> None:
    """A named pipe with mode 600 would block a plain open() until a writer came."""
    fifo = tmp_path / "k"
    os.mkfifo(fifo, 0o600)
    result = subprocess.run([sys.executable, "-m", "tumblebot.pi_agent.agent", "--config",
                             str(write(tmp_path / "a.toml", f'key_file = "{fifo}"\n'))],
                            capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [f"tumblebot-agent: error: key file {fifo} is not a regular file"]


def test_that_the_agent_command_prints_one_error_line_for_a_missing_config(tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "tumblebot.pi_agent.agent", "--config", str(tmp_path / "no.toml")],
                            capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [f"tumblebot-agent: error: config file {tmp_path / 'no.toml'} "
                                                  "does not exist"]


def test_that_the_agent_runs_where_only_pyserial_is_installed() -> None:
    """As on a Pi with `tumblebot[agent]`: numpy, gymnasium, PyBullet and torch unimportable."""
    code = ("import sys\n"
            "for m in ('numpy', 'gymnasium', 'pybullet', 'torch', 'scipy'): sys.modules[m] = None\n"
            "import tumblebot.pi_agent.agent, tumblebot.pi_agent.protocol\n"
            "assert not [m for m in sys.modules if m.startswith('tumblebot.sim')]\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
