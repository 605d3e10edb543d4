"""The digital twin: the deployed stack (host, agent, firmware in simavr) against the
simulator, each component its own process over the lab's links."""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.helpers import tb as run_tumblebot
from tumblebot.host.link import AgentClient, load_host_key
from tumblebot.host.mocap import open_source
from tumblebot.host.trial_runner import ControllerConfig, TrialResult, TrialRunner
from tumblebot.host.trial_sets import TwinPlacer, load_index
from tumblebot.host.triallog import read_trial
from tumblebot.host.twin import TwinStack
from tumblebot.sim.world.design import Design

pytestmark = [pytest.mark.hil, pytest.mark.slow]
XI3 = Design(0.292, 0.129, 0.098, 0.136)
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


def tb(*args: str, timeout: float = 1200) -> subprocess.CompletedProcess[str]:
    return run_tumblebot(*args, timeout=timeout, env=ENV)


def control(stack: TwinStack, msg: dict[str, Any]) -> dict[str, Any]:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(5)
        s.sendto(json.dumps(msg).encode(), ("127.0.0.1", stack.control_port))
        return json.loads(s.recv(4096))  # type: ignore[no-any-return]


def test_that_three_navigation_trials_through_the_twin_agree_with_pure_simulation(tmp_path: Path) -> None:
    """The twin runs in real time, so a starved machine shifts its errors by timing alone
    (measured on 2 cores under three busy loops: trial-set medians 0.12–0.34 m against
    0.10–0.12 m unloaded, with the world dropping no simulated time). A second trial set,
    with another seed, is run when the first is NOT CONSISTENT: the world draws its motor
    noise from the seed, so a set repeated with the same seed repeats its draw, and a draw
    in the tail (seed 0's, for the dual policy: p = 0.005 and 0.019 in two sets) would fail
    both. A starved agent sending no telemetry for 1.5 s trips the host's safety stop,
    which aborts the trial as agent_lost and redoes it (seen on 2 cores under two busy
    loops); that is the product working, so only other aborts fail the test. A real
    frame, servo-direction, timing or link bug fails both sets
    (``tests/host/test_twin_check.py`` shows the check catches each of the first three)."""
    verdicts = []
    for attempt in range(2):  # the second set with another seed: the world's motor noise is the
        out = tmp_path / f"twin-{attempt}"  # seed's, so the same seed would repeat a tail draw
        run = tb("twin", "run", "--out", str(out), "--points", "3", "--per-point", "1", "--check",
                 "--seed", str(attempt))
        aborted = load_index(out)["aborted"] if run.returncode == 0 else None
        verdicts.append(run.stdout.strip().splitlines()[-2:] + run.stderr[-1000:].splitlines()
                        + [f"aborted trials: {aborted}"])
        if run.returncode == 0:
            break
    assert run.returncode == 0, ("both trial sets failed (NOT CONSISTENT, or the command failed):\n"
                                 + "\n".join(map(str, verdicts)))
    # a starved agent's silence aborts a trial as agent_lost, and the set redoes it; nothing else may
    assert aborted is not None and all(a["status"] == "agent_lost" for a in aborted), aborted
    assert "CONSISTENT" in run.stdout
    check = json.loads((out / "consistency.json").read_text())
    assert check["consistent"] and check["twin_n"] == 3
    index = load_index(out)
    assert len(index["trials"]) == 3
    for entry in index["trials"]:
        log = read_trial(out / entry["file"])
        assert log.complete and len(log.topic("/decision")) == 20
    analysis = tb("trial", "analyze", str(out), "--baseline-mean", "0.433", "--baseline-sd", "0.25",
                  "--baseline-n", "100", "--json")
    assert analysis.returncode == 0, analysis.stderr
    result = json.loads(analysis.stdout)
    assert result["n"] == 3 and 0 <= result["baseline"]["p"] <= 1 and len(result["per_point"]) == 3
    assert (out / "analysis.png").stat().st_size > 10_000


def _connected_client(stack: TwinStack) -> AgentClient:
    client = AgentClient(("127.0.0.1", stack.agent_port), load_host_key(stack.key))
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        client.request_telemetry()
        time.sleep(0.2)
        if any(t.get("serial_connected") for t in client.poll()):
            return client
    raise AssertionError("the agent never heard the firmware's READY")


def test_that_losing_mocap_in_the_twin_has_the_servos_neutral(tmp_path: Path) -> None:
    """Through every process of the stack; the controller's own timer is held to its
    ``lost_after`` in tests/host/test_trial_runner.py, so here a bound only says how long
    to wait (a busy machine makes every process later)."""
    class Forward:
        def act(self, obs: np.ndarray) -> np.ndarray:
            return np.array([2, 2])

    with TwinStack(tmp_path, XI3, seed=3) as stack:
        client = _connected_client(stack)
        source = open_source(stack.mocap_url)
        TwinPlacer(("127.0.0.1", stack.control_port)).place(0, (0.0, 0.0), 0.0)
        controller = TrialRunner(source, client, Forward(), (3.0, 0.0), 0.0, ControllerConfig(steps=30))
        results: list[TrialResult] = []
        worker = threading.Thread(target=lambda: results.append(controller.run_trial()))
        worker.start()
        deadline = time.monotonic() + 10
        while True:  # driving forward: right servo long pulses, the mirrored left one short
            right, left = control(stack, {"cmd": "status"})["widths"]
            if right is not None and left is not None and abs(right - 2000.0) < 2 and abs(left - 1000.0) < 2:
                break
            assert time.monotonic() < deadline, (right, left)
            time.sleep(0.05)
        time.sleep(1.0)
        control(stack, {"cmd": "mocap", "on": False})
        lost = time.monotonic()
        while True:
            widths = control(stack, {"cmd": "status"})["widths"]
            if all(w is not None and abs(w - 1500.0) < 2 for w in widths):
                break
            assert time.monotonic() - lost < 10.0, f"servos still at {widths} 10 s after the dropout"
            time.sleep(0.01)
        worker.join(timeout=10)
        assert results and results[0].status == "mocap_lost"
        source.close()
        client.close()


def _host(stack: TwinStack, out: Path, *extra: str) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "tumblebot.cli", "trial", "run", "--out", str(out), "--design",
           "0.292,0.129,0.098,0.136", "--setpoint", "0.4,-0.3", "--steps", "6", "--period", "0.5",
           *stack.host_args(), *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV,
                            stdin=subprocess.DEVNULL)


def _read_until(proc: subprocess.Popen[str], marker: str, seen: list[str], timeout: float = 60) -> None:
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            raise AssertionError(f"host exited before {marker!r}: {''.join(seen[-20:])}")
        seen.append(line)
        if marker in line:
            return
    raise AssertionError(f"no {marker!r} within {timeout} s")


def test_that_a_killed_agent_is_reported_and_a_restarted_one_lets_the_set_continue(tmp_path: Path) -> None:
    out = tmp_path / "set"
    with TwinStack(tmp_path, XI3, seed=4) as stack:
        _connected_client(stack).close()
        host = _host(stack, out, "--points", "2", "--per-point", "1", "--agent-wait", "60")
        seen: list[str] = []
        _read_until(host, "step  2/", seen)
        stack.kill_agent()
        _read_until(host, "waiting for the agent", seen)
        assert any("aborted (agent_lost)" in line for line in seen)
        stack.start_agent()
        _read_until(host, "answers again", seen)
        rest, _ = host.communicate(timeout=120)
        assert host.returncode == 0, rest
    index = load_index(out)
    assert [t["trial"] for t in index["trials"]] == [0, 1]
    # the kill aborts the first trial; a restarted agent starved of the CPU on a loaded machine
    # can fall silent for the host's 1.5 s as well (seen once in a loaded CI run), which is
    # another agent_lost and a redo, and never any other abort
    statuses = [a["status"] for a in index["aborted"]]
    assert index["aborted"][0]["trial"] == 0 and set(statuses) == {"agent_lost"}, (index["aborted"], rest)


def test_that_kill_9_of_the_host_at_random_moments_loses_no_written_step(tmp_path: Path) -> None:
    rng = random.Random(7)
    out = tmp_path / "set"
    with TwinStack(tmp_path, XI3, seed=5) as stack:
        _connected_client(stack).close()
        for attempt in range(4):
            host = _host(stack, out, "--points", "1", "--per-point", "3", "--print-writes")
            assert host.stdout is not None
            written: list[int] = []
            current = None
            started = None
            while True:
                line = host.stdout.readline()
                if not line:
                    break
                if line.startswith("trial "):
                    current, written = int(line.split()[1].split("/")[0]) - 1, []
                elif line.startswith("@written"):
                    written.append(int(line.split()[1]))
                    started = started or time.monotonic()
                if started and time.monotonic() - started > rng.uniform(0.5, 6.0):
                    break
            host.send_signal(signal.SIGKILL)
            rest, _ = host.communicate()
            written += [int(ln.split()[1]) for ln in rest.splitlines() if ln.startswith("@written")]
            assert current is not None
            path = out / f"trial-{current:04d}.mcap"
            if path.exists():  # killed mid-trial (else between trials: nothing open)
                got = {m.sequence for m in read_trial(path).messages}
                assert set(written) <= got, f"attempt {attempt}: lost {sorted(set(written) - got)[:5]}"
            for entry in load_index(out)["trials"]:  # finished trials are untouched
                assert read_trial(out / entry["file"]).complete
        finish = _host(stack, out, "--points", "1", "--per-point", "3")
        rest, _ = finish.communicate(timeout=180)
        assert finish.returncode == 0, rest
    index = load_index(out)
    assert sorted(t["trial"] for t in index["trials"]) == [0, 1, 2]
    # Each kill leaves a trial the next run records as host_crashed. On a machine starved of
    # CPU the agent can also miss telemetry for longer than the 1.5 s agent timeout; that
    # trial is then aborted as agent_lost and redone, which is the product working (the
    # agent-loss path has its own test above). Nothing else may abort a trial.
    assert all(a["status"] in ("host_crashed", "agent_lost") for a in index["aborted"]), index["aborted"]
