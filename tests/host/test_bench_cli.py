"""``tumblebot trim`` and ``tumblebot bench check`` against the real agent as a process and
the real firmware in simavr (no pose source: the checks that need one say so)."""

from __future__ import annotations

import itertools
import json
import math
import time
from pathlib import Path

import pytest

from tests.helpers import tb, tb_ok
from tumblebot.host.bench import body_roll, motion, resting_frame
from tumblebot.host.emulator import EmulatedUno
from tumblebot.host.mocap import Pose

pytestmark = pytest.mark.hil




def test_that_trim_shows_sets_and_persists_the_trims_in_the_firmware(
        uno_and_agent: tuple[EmulatedUno, str, Path]) -> None:
    uno, address, key = uno_and_agent
    link = ["--agent", address, "--key", str(key)]
    shown = tb_ok("trim", *link)
    assert shown.stdout.strip() == "trims: right 1500 µs +1, left 1500 µs -1"
    nudged = tb_ok("trim", *link, "--servo", "right", "--nudge", "12")
    assert "right servo: neutral 1500 → 1512 µs, direction +1 → +1" in nudged.stdout
    flipped = tb("trim", *link, "--servo", "left", "--neutral", "1490", "--direction", "+1", "--json")
    assert json.loads(flipped.stdout) == {"servo": "left", "before": {"neutral_us": 1500, "direction": -1},
                                          "after": {"neutral_us": 1490, "direction": 1}}
    # The pulses follow the trims: stopped, each servo sits at its neutral.
    uno.wait_for(1512, 1490, tolerance=2.0)
    uno.reset()  # a new boot reads the trims back from EEPROM
    time.sleep(1.0)
    again = tb("trim", *link, "--json")
    assert json.loads(again.stdout) == {"right": {"neutral_us": 1512, "direction": 1},
                                        "left": {"neutral_us": 1490, "direction": 1}}


@pytest.mark.parametrize("args, message", [
    (("--servo", "left", "--neutral", "1800"), "1800 µs is outside 1300–1700 µs"),
    (("--servo", "left", "--direction", "0"), "'0' must be +1 or -1"),
    (("--servo", "left"), "say what to change"),
    (("--neutral", "1500"), "need --servo right|left"),
    (("--servo", "right", "--neutral", "1500", "--nudge", "5"), "not both"),
    (("--servo", "right", "--nudge", "-250"), "outside 1300–1700 µs"),
])
def test_that_a_bad_trim_is_refused_in_one_line_and_changes_nothing(
        uno_and_agent: tuple[EmulatedUno, str, Path], args: tuple[str, ...], message: str) -> None:
    _, address, key = uno_and_agent
    link = ["--agent", address, "--key", str(key)]
    refused = tb("trim", *link, *args)
    assert refused.returncode == 2 and message in refused.stderr
    assert len(refused.stderr.strip().splitlines()) == 1 or "usage:" in refused.stderr
    assert json.loads(tb("trim", *link, "--json").stdout)["left"] == {"neutral_us": 1500, "direction": -1}


def test_that_the_agent_forwards_no_trim_while_the_robot_moves(uno_and_agent: tuple[EmulatedUno, str, Path]) -> None:
    """A trim changes the pulses under a moving leg: the agent refuses it (``busy``)."""
    from tumblebot.host.link import AgentClient, load_host_key, parse_address

    uno, address, key = uno_and_agent
    client = AgentClient(parse_address(address), load_host_key(key))
    try:
        assert client.telemetry_until(10, lambda body: bool(body.get("serial_connected"))) is not None
        deadline = time.monotonic() + 10
        body: dict[str, object] | None = None
        while time.monotonic() < deadline:
            client.command(1, 1)
            client.set_trim(0, 1600, -1)
            time.sleep(0.2)
            body = client.telemetry_until(1, lambda b: b.get("drops", {}).get("busy", 0) >= 3)
            if body is not None:
                break
        assert body is not None
        assert body["trims_forwarded"] == 0
        client.stop()
    finally:
        client.close()
    uno.wait_for(1500, 1500)


def test_that_bench_check_fails_on_an_unplugged_arduino_naming_it(unplugged_agent: tuple[str, Path]) -> None:
    address, key = unplugged_agent
    run = tb("bench", "check", "--agent", address, "--key", str(key), "--json")
    assert run.returncode == 1
    checks = {c["check"]: c for c in json.loads(run.stdout)["checks"]}
    assert checks["agent"]["ok"] is True
    assert checks["arduino"]["ok"] is False and "not connected" in checks["arduino"]["detail"]
    assert all(checks[name]["ok"] is None for name in ("trims", "still", "servos", "watchdog"))


def test_that_bench_check_fails_when_no_agent_answers(tmp_path: Path) -> None:
    from tumblebot.host.link import free_port, new_key

    key = tmp_path / "agent.key"
    new_key(key)
    run = tb("bench", "check", "--agent", f"127.0.0.1:{free_port()}", "--key", str(key))
    assert run.returncode == 1
    assert "agent     FAIL no answer from 127.0.0.1:" in run.stdout
    assert run.stdout.strip().endswith("NOT READY: fix what failed and run bench check again")


def test_that_bench_check_without_poses_or_operator_checks_the_link_and_the_watchdog(
        agent: tuple[str, Path]) -> None:
    address, key = agent
    run = tb("bench", "check", "--agent", address, "--key", str(key), "--json")
    result = json.loads(run.stdout)
    checks = {c["check"]: c for c in result["checks"]}
    assert [c["check"] for c in result["checks"]] == ["agent", "arduino", "trims", "mocap", "still", "servos",
                                                      "watchdog"]
    assert checks["arduino"]["ok"] and "firmware 1.1.0 (protocol 1)" in checks["arduino"]["detail"]
    assert checks["trims"]["ok"] and checks["trims"]["detail"].startswith("right 1500 µs +1, left 1500 µs -1")
    assert checks["watchdog"]["ok"], checks["watchdog"]
    assert checks["servos"]["ok"] is None and "needs --mocap or an operator" in checks["servos"]["detail"]
    assert run.returncode == 1 and result["passed"] is False  # not everything could be checked


def _pose(t: float, roll: float, xy: tuple[float, float] = (0.0, 0.0)) -> Pose:
    return Pose(t, (xy[0], xy[1], 0.05), (math.sin(roll / 2), 0.0, 0.0, math.cos(roll / 2)))


def test_that_body_roll_sums_turns_about_the_leg_axis_through_whole_tumbles() -> None:
    poses = [_pose(0.01 * k, 0.05 * k) for k in range(200)]  # 10 rad: more than a full turn
    assert body_roll(poses) == pytest.approx(9.95, abs=1e-6)
    assert body_roll(poses[::-1]) == pytest.approx(-9.95, abs=1e-6)
    assert motion([_pose(0, 0.0), _pose(1, 0.1, (0.003, 0.004))]) == pytest.approx((0.005, 0.1))
    level, face, tilt = resting_frame(_pose(0, math.pi / 2))  # rolled a quarter turn: resting on a side
    assert level == pytest.approx(0.0, abs=1e-9) and face == "+y" and tilt == pytest.approx(0.0, abs=1e-6)


@pytest.mark.slow
def test_that_bench_excite_runs_the_identification_run_as_a_trial_set(tmp_path: Path,
                                                                      agent: tuple[str, Path]) -> None:
    """One start point, one run: the robot (a still mock pose at the start point) is driven by
    the scripted commands, logged like any trial, with the time each command left."""
    from tumblebot.host.trial_sets import load_index
    from tumblebot.host.triallog import read_trial
    from tumblebot.sim.control.gaits import EXCITATION

    address, key = agent
    out = tmp_path / "excite"
    run = tb("bench", "excite", "--out", str(out), "--mocap", "mock://?x=1.5&y=0", "--agent", address, "--key",
             str(key), "--design", "0.292,0.129,0.098,0.136", "--radius", "1.5", "--points", "1", "--per-point", "1",
             timeout=300)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    assert json.loads((out / "plan.json").read_text())["policy"] == "excite"
    [trial] = load_index(out)["trials"]
    decisions = read_trial(out / trial["file"]).topic("/decision")
    assert [tuple(d.data["command"]) for d in decisions] == [(a - 1, b - 1) for a, b in EXCITATION]
    times = [d.data["t"] for d in decisions]
    assert all(0.9 < b - a < 1.2 for a, b in itertools.pairwise(times))
    again = tb("bench", "excite", "--out", str(out), "--mocap", "mock://?x=1.5&y=0", "--agent", address, "--key",
               str(key), "--design", "0.292,0.129,0.098,0.136", "--radius", "1.5", "--points", "1", "--per-point",
               "1", timeout=120)  # the same command resumes: nothing left to run
    assert again.returncode == 0 and len(load_index(out)["trials"]) == 1, again.stderr
