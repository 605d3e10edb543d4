"""``tumblebot trial run`` / ``analyze`` as an operator uses them (mock mocap, the real agent
as a process, with the real firmware in simavr on its serial port, or with nothing there:
pyserial's loop://, an unplugged Arduino)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.helpers import tb, tb_ok
from tumblebot.host.link import new_key
from tumblebot.host.trial_sets import load_index


def run_args(out: Path, address: str, key: Path, *extra: str) -> list[str]:
    return ["trial", "run", "--out", str(out), "--mocap", "mock://?x=1.5&y=0", "--agent", address, "--key", str(key),
            "--design", "0.292,0.129,0.098,0.136", "--points", "1", "--per-point", "2", "--steps", "3",
            "--period", "0.2", *extra]


@pytest.mark.slow
@pytest.mark.hil
def test_that_an_operator_trial_set_runs_records_and_analyses(tmp_path: Path, agent: tuple[str, Path]) -> None:
    address, key = agent
    out = tmp_path / "set"
    run = tb(*run_args(out, address, key))
    assert run.returncode == 0, run.stdout + run.stderr
    assert "place the robot at (+1.50, +0.00)" in run.stdout and "trial set complete: 2 trials" in run.stdout
    index = load_index(out)
    assert [t["final_error"] for t in index["trials"]] == pytest.approx([1.5, 1.5], abs=1e-6)
    again = tb(*run_args(out, address, key))  # nothing left: resuming a finished set does nothing
    assert again.returncode == 0 and "trial 1/2" not in again.stdout
    changed = tb(*run_args(out, address, key, "--radius", "1.0"))
    assert changed.returncode == 2 and "different trial set" in changed.stderr
    analysis = tb_ok("trial", "analyze", str(out), "--baseline-mean", "0.433", "--baseline-sd", "0.2",
                     "--baseline-n", "100", "--json")
    result = json.loads(analysis.stdout)
    assert result["n"] == 2 and result["mean_error"] == pytest.approx(1.5) and result["baseline"]["p"] < 0.01
    assert result["e"] == pytest.approx(5.22, abs=0.05)
    base = tb("trial", "analyze", str(out), "--baseline", str(out), "--json")
    assert json.loads(base.stdout)["baseline"]["n"] == 2


@pytest.mark.slow
def test_that_a_trial_set_against_an_agent_with_no_arduino_records_no_finished_trial(
        tmp_path: Path, unplugged_agent: tuple[str, Path]) -> None:
    address, key = unplugged_agent
    out = tmp_path / "set"
    run = tb(*run_args(out, address, key))
    assert run.returncode == 2, run.stdout + run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "no trial started" in lines[0] and "serial_connected: false" in lines[0], lines
    assert "done: final error" not in run.stdout and "Traceback" not in run.stderr
    assert not out.exists() or not load_index(out)["trials"]


def test_that_bad_trial_input_gets_one_clear_error(tmp_path: Path) -> None:
    loose = tmp_path / "loose.key"
    loose.write_bytes(bytes(32))
    loose.chmod(0o644)
    key = tmp_path / "k"
    new_key(key)
    out = tmp_path / "s"
    cases = [
        (run_args(out, "127.0.0.1:47800", loose), "accessible by group or others"),
        (run_args(out, "127.0.0.1:notaport", key), "not a number"),
        (run_args(out, "127.0.0.1:47800", key, "--radius", "-1"), "--radius"),
        (run_args(out, "127.0.0.1:47800", key, "--design", "0.1,0.1,0.1,0.1"), "outside its bound"),
        (run_args(out, "127.0.0.1:47800", key, "--policy", "nope.onnx"), "does not exist"),
        (run_args(out, "127.0.0.1:47800", key, "--setpoint", "1"), "two numbers"),
        (run_args(out, "127.0.0.1:47800", key, "--period", "0"), "period"),
        (run_args(out, "127.0.0.1:47800", key, "--foxglove", "web"), "expected PORT or HOST:PORT"),
        (run_args(out, "127.0.0.1:47800", key, "--foxglove", "70000"), "expected PORT or HOST:PORT"),
    ]
    for args, message in cases:
        run = tb(*args, timeout=60)
        assert run.returncode == 2, (args, run.stderr)
        assert message in run.stderr and "Traceback" not in run.stderr, (args, run.stderr)
    assert not out.exists()  # nothing was created by a refused command
    missing = tb("trial", "analyze", str(tmp_path / "nothing"))
    assert missing.returncode == 2 and "not a trial set" in missing.stderr
    partial = tb("trial", "analyze", str(tmp_path), "--baseline-mean", "0.4")
    assert partial.returncode == 2 and "--baseline-sd" in partial.stderr


def test_that_twin_run_refuses_a_bad_live_view_address_before_starting(tmp_path: Path) -> None:
    run = tb("twin", "run", "--out", str(tmp_path / "t"), "--foxglove", "localhost:", timeout=60)
    assert run.returncode == 2 and "expected PORT or HOST:PORT" in run.stderr, run.stderr
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize("gait", ["excite", "pulse"])
def test_that_twin_run_refuses_to_check_a_scripted_gait_before_starting(tmp_path: Path, gait: str) -> None:
    """A scripted gait runs open loop (held-out or identification trials for a calibration):
    there is no policy to simulate beside it, so ``--check`` is one error line."""
    run = tb("twin", "run", "--out", str(tmp_path / "t"), "--policy", gait, "--check", timeout=60)
    assert run.returncode == 2 and f"a scripted gait (--policy {gait}) runs open loop" in run.stderr, run.stderr
    assert not (tmp_path / "t").exists()


@pytest.mark.slow
@pytest.mark.hil
def test_that_a_replayed_trial_reproduces_the_recording_regression_start_wait_ate_the_recording(
        tmp_path: Path, agent: tuple[str, Path]) -> None:
    """replay:// of a recorded trial aborted at step 19 of 20 with mocap_lost: the host's 1 s
    wait at the start point used up part of the recording. The replay holds the start until
    the trial begins, so every step sees the pose it saw when recorded."""
    from tests.calibration_logs import write_set
    from tumblebot.host.triallog import read_trial
    from tumblebot.sim.world.physics import THESIS

    recorded = write_set(tmp_path / "recorded", THESIS, 1)
    log = read_trial(recorded / "trial-0000.mcap")
    poses = [(m.log_time, m.data["p"]) for m in log.topic("/pose")]
    t0 = poses[0][0]
    address, key = agent
    out = tmp_path / "replayed"
    run = tb("trial", "run", "--out", str(out), "--mocap", f"replay://{recorded / 'trial-0000.mcap'}",
             "--agent", address, "--key", str(key), "--design", "0.292,0.129,0.098,0.136", "--setpoint", "0,0",
             "--heading", "0", "--radius", "1", "--points", "1", "--per-point", "1", "--gait", "excite", timeout=180)
    assert run.returncode == 0, run.stdout + run.stderr
    index = load_index(out)
    assert len(index["trials"]) == 1 and not index["aborted"], index
    final = load_index(recorded)["trials"][0]["final_position"]
    assert index["trials"][0]["final_position"][:2] == pytest.approx(final[:2], abs=0.01)
    replayed = read_trial(out / "trial-0000.mcap")
    start = next(m.data["t"] for m in replayed.topic("/pose"))  # host clock, as the decisions' "t"
    decisions = list(replayed.topic("/decision"))
    assert len(decisions) == 20
    for decision in decisions:
        when = decision.data["t"] - start  # seconds into the trial, as replayed
        near = min(poses, key=lambda tp: abs(tp[0] - t0 - when))[1]
        seen = decision.data["observation"][:2]
        assert seen == pytest.approx(near[:2], abs=0.03), (decision.data["step"], seen, near)
