"""The agent's configuration and key file: bad input is one clear error."""

from __future__ import annotations

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
    key.write_bytes(bytes(32))
    key.chmod(0o644)
    with pytest.raises(AgentError, match="accessible by group or others"):
        load_key(key)
    key.chmod(0o600)
    assert load_key(key) == bytes(32)
    key.write_bytes(bytes(31))
    with pytest.raises(AgentError, match="exactly 32 bytes"):
        load_key(key)


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
