"""``tumblebot bench check`` against the digital twin's stack (world, firmware in simavr,
agent), with the twin's pose stream as the motion capture: it passes on a healthy robot
and fails, naming the fault, with a servo reversed (in the firmware's trim, or mounted the
other way round in the world), or a neutral trim off."""

from __future__ import annotations

import json
import os
import socket
import subprocess
from pathlib import Path
from typing import Any

import pytest

from tests.helpers import tb as run_tumblebot
from tumblebot.host.twin import TwinStack
from tumblebot.sim.world.design import Design

pytestmark = [pytest.mark.hil, pytest.mark.slow]
XI3 = Design(0.292, 0.129, 0.098, 0.136)
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


def tb(*args: str, timeout: float = 1200) -> subprocess.CompletedProcess[str]:
    return run_tumblebot(*args, timeout=timeout, env=ENV)


def place(stack: TwinStack, trial: int) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(10)
        s.sendto(json.dumps({"cmd": "place", "trial": trial, "x": 0.0, "y": 0.0, "yaw": 0.3}).encode(),
                 ("127.0.0.1", stack.control_port))
        assert json.loads(s.recv(4096))["ok"]


def link(stack: TwinStack) -> list[str]:
    return ["--agent", f"127.0.0.1:{stack.agent_port}", "--key", str(stack.key)]


def bench_check(stack: TwinStack) -> tuple[int, dict[str, dict[str, Any]]]:
    run = tb("bench", "check", *link(stack), "--mocap", stack.mocap_url, "--json")
    assert run.stdout, run.stderr
    result = json.loads(run.stdout)
    assert result["passed"] == (run.returncode == 0)
    return run.returncode, {c["check"]: c for c in result["checks"]}


def test_that_bench_check_passes_on_the_twin_and_names_a_reversed_servo_or_a_trim_off(tmp_path: Path) -> None:
    with TwinStack(tmp_path, XI3, seed=0) as stack:
        place(stack, 0)
        code, checks = bench_check(stack)
        assert code == 0, [c for c in checks.values() if not c["ok"]]
        assert "firmware 1.1.0" in checks["arduino"]["detail"]
        assert "leg axis level" in checks["mocap"]["detail"]

        trim = tb("trim", *link(stack), "--servo", "right", "--direction", "-1")
        assert trim.returncode == 0, trim.stderr
        code, checks = bench_check(stack)
        assert code == 1
        assert checks["servos"]["ok"] is False
        assert checks["servos"]["detail"].startswith("right servo reversed"), checks["servos"]
        assert "tumblebot trim --servo right --direction +1" in checks["servos"]["fix"]
        assert checks["trims"]["ok"], checks["trims"]
        assert checks["watchdog"]["ok"], checks["watchdog"]

        assert tb("trim", *link(stack), "--servo", "right", "--direction", "+1").returncode == 0
        assert tb("trim", *link(stack), "--servo", "left", "--neutral", "1580").returncode == 0
        code, checks = bench_check(stack)
        assert code == 1
        assert checks["trims"]["ok"] is False
        assert "left neutral 1580 µs is +80 µs off 1500 µs" in checks["trims"]["detail"]
        assert "tumblebot trim --servo left" in checks["trims"]["fix"]


def test_that_bench_check_names_a_servo_mounted_the_other_way_round(tmp_path: Path) -> None:
    with TwinStack(tmp_path, XI3, seed=1, world_args=["--reverse-servo", "left"]) as stack:
        place(stack, 1)
        code, checks = bench_check(stack)
        assert code == 1
        assert checks["servos"]["detail"].startswith("left servo reversed"), checks["servos"]
        assert "tumblebot trim --servo left --direction +1" in checks["servos"]["fix"]
        failed = [c for name, c in checks.items() if name != "servos" and not c["ok"]]
        assert not failed, failed
