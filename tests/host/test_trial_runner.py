"""The controller against the real agent (in a thread) with the real firmware in simavr on
its serial port, and a UDP pose stream: decisions, frames, and every way a trial stops the
robot, including the link faults that mean the robot could not have moved (an unplugged
USB cable, a firmware reboot, commands the firmware never ran)."""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from tumblebot.defaults import XI3_ROBOT
from tumblebot.host.emulator import EmulatedUno
from tumblebot.host.link import AgentClient
from tumblebot.host.mocap import encode_pose_datagram, open_source
from tumblebot.host.trial_runner import ControllerConfig, TrialRunner, _TrialState
from tumblebot.host.triallog import TrialLogWriter, read_trial
from tumblebot.pi_agent.agent import Agent, AgentConfig
from tumblebot.sim.control.policy import OnnxPolicy, bundled_policy
from tumblebot.sim.world.frames import yaw_quaternion

KEY = bytes(range(32))
pytestmark = pytest.mark.hil  # the lab's Arduino is the real firmware in simavr


@dataclass
class Publisher:
    """A mocap system: poses of a robot at ``position``/``yaw`` at 100 Hz while ``on``."""

    address: tuple[str, int]
    position: tuple[float, float, float] = (1.0, 0.5, 0.05)
    yaw: float = 0.3
    on: bool = True
    stopped_at: float | None = None
    _stop: threading.Event = field(default_factory=threading.Event)

    def run(self) -> None:

        seq = 0
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            while not self._stop.is_set():
                if self.on:
                    seq += 1
                    s.sendto(encode_pose_datagram("tumbler", seq, time.time(), self.position,
                                                  yaw_quaternion(self.yaw)), self.address)
                time.sleep(0.01)

    def dropout(self) -> None:
        self.on = False
        self.stopped_at = time.monotonic()


@dataclass
class Lab:
    publisher: Publisher
    agent: Agent
    client: AgentClient
    source: object
    stop_agent: threading.Event
    agent_thread: threading.Thread
    uno: EmulatedUno | None = None

    def controller(self, policy: object, **cfg: float) -> TrialRunner:
        config = ControllerConfig(**{"period": 0.1, "steps": 5, **cfg})  # type: ignore[arg-type]
        return TrialRunner(self.source, self.client, policy, (0.2, -0.1), 0.4, config)  # type: ignore[arg-type]

    def kill_agent(self) -> None:
        self.stop_agent.set()
        self.agent_thread.join()


def _lab(serial_port: str | None) -> Iterator[Lab]:
    """A lab whose agent talks to the firmware in simavr, or to ``serial_port`` (``loop://``:
    an agent whose Arduino is unplugged)."""
    uno = EmulatedUno() if serial_port is None else None
    source = open_source("udp://127.0.0.1:0?body=tumbler")
    publisher = Publisher(source.address)  # type: ignore[attr-defined]
    pub_thread = threading.Thread(target=publisher.run, daemon=True)
    pub_thread.start()
    agent = Agent(AgentConfig(serial_port=uno.pty if uno else str(serial_port), bind_address="127.0.0.1",
                              bind_port=0, allowed_host="127.0.0.1"), KEY)
    stop_agent = threading.Event()
    agent_thread = threading.Thread(target=agent.run, args=(stop_agent.is_set,), daemon=True)
    agent_thread.start()
    client = AgentClient(agent.address, KEY)
    try:
        if uno is not None:
            wait_until(lambda: agent.link.ready, "the agent to hear the firmware", timeout=30)
        yield Lab(publisher, agent, client, source, stop_agent, agent_thread, uno)
    finally:
        publisher._stop.set()
        stop_agent.set()
        agent_thread.join(timeout=2)
        source.close()
        client.close()
        if uno is not None:
            uno.close()


@pytest.fixture
def lab() -> Iterator[Lab]:
    yield from _lab(None)


@pytest.fixture
def unplugged_lab() -> Iterator[Lab]:
    yield from _lab("loop://")


def wait_until(condition: Callable[[], bool], what: str, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"waited {timeout} s for {what}"
        time.sleep(0.005)


class Scripted:
    """A policy that records what it saw and answers from a script."""

    def __init__(self, actions: list[tuple[int, int]], raise_at: int | None = None) -> None:
        self.actions, self.raise_at, self.seen = actions, raise_at, []  # type: ignore[var-annotated]

    def act(self, obs: np.ndarray) -> np.ndarray:
        self.seen.append(obs.copy())
        if self.raise_at is not None and len(self.seen) > self.raise_at:
            raise KeyboardInterrupt
        return np.array(self.actions[(len(self.seen) - 1) % len(self.actions)])


def test_that_a_trial_makes_its_decisions_on_task_frame_poses_and_ends_stopped(lab: Lab, tmp_path: Path) -> None:
    policy = Scripted([(2, 0), (1, 1)])
    with TrialLogWriter(tmp_path / "t.mcap") as log:
        result = lab.controller(policy).run_trial(log)
    assert result.status == "complete" and result.decisions == 5
    # Lab pose (1.0, 0.5) with setpoint (0.2, -0.1) and heading 0.4 rad, in the task frame:
    dx, dy = 1.0 - 0.2, 0.5 + 0.1
    expect = (math.cos(0.4) * dx + math.sin(0.4) * dy, -math.sin(0.4) * dx + math.cos(0.4) * dy)
    obs = policy.seen[0]
    assert obs[:2] == pytest.approx(expect, abs=1e-5)
    assert 2 * math.atan2(obs[5], obs[6]) == pytest.approx(0.3 - 0.4, abs=1e-5)
    assert list(obs[7:]) == [0, 0] and list(policy.seen[1][7:]) == [1, -1]  # the last command is observed
    assert result.final_error == pytest.approx(math.hypot(dx, dy), abs=1e-4)
    assert len(result.latencies_ms) == 5 and min(result.latencies_ms) >= 0  # (benchmarks/bench_link.py times them)
    log_ = read_trial(tmp_path / "t.mcap")
    assert len(log_.topic("/decision")) == 5 and log_.topic("/telemetry") and log_.topic("/pose")
    wait_until(lambda: lab.agent.command == (0, 0), "the agent to be told to stop")


@pytest.fixture(scope="module")
def bundled_nav_policy() -> OnnxPolicy:
    """The bundled nav-flat policy, loaded before any lab starts. The first load imports
    ONNX Runtime, whose library loading holds the interpreter for over a second; the
    emulated Uno's event reader is a thread of this process, so simulated time stalls
    with it, and the agent (also a thread here) rightly calls the silence a lost serial
    link. In a lab the agent runs on the Pi and the firmware on the Uno."""
    policy = OnnxPolicy(bundled_policy("nav-flat"), task="nav-flat")
    policy.bind_design(XI3_ROBOT)  # as trial run --design does; a design-conditioned policy needs it
    return policy


def test_that_the_bundled_policy_drives_the_controller(bundled_nav_policy: OnnxPolicy, lab: Lab) -> None:
    policy = bundled_nav_policy
    policy.reset()
    result = lab.controller(policy).run_trial()
    assert result.status == "complete" and result.decisions == 5


def test_that_mocap_dropout_stops_the_robot(lab: Lab) -> None:
    """The controller stops the robot once no pose came for ``lost_after`` and not before,
    on its own clock, which a busy machine can only make later (so no wall-clock bound)."""
    policy = Scripted([(2, 2)])
    timer = threading.Timer(0.3, lab.publisher.dropout)
    timer.start()
    result = lab.controller(policy, steps=50, lost_after=0.5).run_trial()
    assert result.status == "mocap_lost" and "no pose" in result.reason
    assert float(result.reason.split()[3]) >= 0.5  # "no pose for 0.51 s"
    assert result.stop_latency is not None and result.stop_latency >= 0
    wait_until(lambda: lab.agent.command == (0, 0), "the agent to stop the robot")


def test_that_a_dead_agent_is_reported_and_the_robot_commanded_to_stop(lab: Lab) -> None:
    threading.Timer(0.3, lab.kill_agent).start()
    result = lab.controller(Scripted([(2, 2)]), steps=50, agent_timeout=0.6).run_trial()
    assert result.status == "agent_lost" and "no telemetry" in result.reason


def test_that_no_tracking_at_the_start_never_moves_the_robot(lab: Lab) -> None:
    lab.publisher.on = False
    time.sleep(0.6)
    policy = Scripted([(2, 2)])
    result = lab.controller(policy, first_pose_timeout=0.5).run_trial()
    assert result.status == "no_mocap" and policy.seen == []


def test_that_ctrl_c_stops_the_robot_and_propagates(lab: Lab) -> None:
    policy = Scripted([(2, 2)], raise_at=2)
    with pytest.raises(KeyboardInterrupt):
        lab.controller(policy, steps=10).run_trial()
    wait_until(lambda: lab.agent.command == (0, 0), "the agent to stop the robot")
    assert lab.agent.host_timeouts == 0  # the host's STOP did it, not the agent's watchdog


def test_that_duplicate_and_late_frames_do_not_make_extra_decisions(lab: Lab) -> None:

    policy = Scripted([(1, 1)])

    def noise() -> None:  # replayed old frames from another sender on the same port
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(100):
                s.sendto(encode_pose_datagram("tumbler", 1, 0.0, (5.0, 5.0, 0.05), (0, 0, 0, 1)),
                         lab.publisher.address)
                time.sleep(0.003)

    threading.Thread(target=noise, daemon=True).start()
    result = lab.controller(policy).run_trial()
    assert result.status == "complete" and len(policy.seen) == 5
    assert all(abs(o[0]) < 2 for o in policy.seen)  # never decided on the replayed (5, 5) frames


def _wait_for_session(client: AgentClient, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while client.session is None:
        assert time.monotonic() < deadline, "the agent never told its session"
        client.request_telemetry()
        time.sleep(0.05)
        client.poll()


def test_that_a_host_restarted_within_the_same_second_is_not_refused_as_a_replay(lab: Lab) -> None:
    lab.client.close()

    def stops() -> int:  # a STOP to a stopped robot is counted rate_limited: accepted as fresh all the same
        return lab.agent.accepted + lab.agent.rate_limited.get("STOP", 0)

    before = stops()
    for _ in range(3):  # three host processes in quick succession, each sending a burst
        client = AgentClient(lab.agent.address, KEY)
        _wait_for_session(client)
        for _ in range(50):
            client.stop()
        client.close()
    deadline = time.monotonic() + 10
    while stops() < before + 150:
        assert time.monotonic() < deadline, (stops() - before, dict(lab.agent.drops))
        time.sleep(0.01)
    assert lab.agent.drops.get("replayed", 0) == 0 and lab.agent.drops.get("stale", 0) == 0


def test_that_a_host_follows_an_agent_restart_to_its_new_session(lab: Lab) -> None:
    _wait_for_session(lab.client)
    first = lab.client.session
    port = lab.agent.address[1]
    lab.kill_agent()
    assert lab.uno is not None
    agent = Agent(AgentConfig(serial_port=lab.uno.pty, bind_address="127.0.0.1", bind_port=port,
                              allowed_host="127.0.0.1"), KEY)
    stop = threading.Event()
    thread = threading.Thread(target=agent.run, args=(stop.is_set,), daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 10
        telemetry: list[dict[str, object]] = []
        while lab.client.session in (None, first) or not telemetry:
            assert time.monotonic() < deadline, "the host never adopted the restarted agent's session"
            lab.client.request_telemetry()
            time.sleep(0.1)
            telemetry = lab.client.poll()
        assert lab.client.sessions == 2
    finally:
        stop.set()
        thread.join(timeout=2)


def test_that_goto_drives_the_host_controller_and_starts_every_trial_afresh(lab: Lab) -> None:
    from tumblebot.sim.control.goto import GotoPolicy

    goto = GotoPolicy(5)
    first = lab.controller(goto).run_trial()
    assert first.status == "complete" and goto.step == 5
    second = lab.controller(goto).run_trial()
    assert second.status == "complete" and goto.step == 5  # reset at the start of the trial, not carried over


# --------------------------------------------------------------------- link faults
def test_that_a_trial_with_the_arduino_unplugged_never_starts_and_says_why(unplugged_lab: Lab) -> None:
    """The agent answers, but its serial port (loop://) has no firmware behind it: the
    telemetry says serial_connected: false, and no decision is made."""
    policy = Scripted([(2, 2)])
    result = unplugged_lab.controller(policy).run_trial()
    assert result.status == "serial_lost" and result.decisions == 0 and policy.seen == []
    assert "USB cable" in result.reason


def test_that_unplugging_the_arduino_mid_trial_aborts_the_trial(lab: Lab) -> None:
    assert lab.uno is not None
    uno = lab.uno
    threading.Timer(0.5, uno.close).start()  # the USB cable falls out
    result = lab.controller(Scripted([(2, 2)]), steps=200).run_trial()
    assert result.status == "serial_lost" and 0 < result.decisions < 200


def test_that_a_firmware_reboot_mid_trial_aborts_the_trial(lab: Lab) -> None:
    assert lab.uno is not None
    uno = lab.uno
    threading.Timer(0.5, uno.reset).start()  # a brown-out resets the Uno
    result = lab.controller(Scripted([(2, 2)]), steps=200).run_trial()
    assert result.status in ("firmware_reboot", "no_ack", "serial_lost"), result
    assert result.status == "firmware_reboot", result.reason


def test_that_commands_the_firmware_does_not_run_abort_the_trial(unplugged_lab: Lab) -> None:
    """The rule on its own: telemetry whose firmware status shows other speeds than the
    command held for ack_timeout (the firmware's watchdog holding the servos) is a fault;
    before ack_timeout, and when the status shows the command, it is not."""
    runner = unplugged_lab.controller(Scripted([(2, 2)]), ack_timeout=1.0)
    state = _TrialState.starting(100.0, runner.config, epoch=7)
    runner.command = (1, 1)
    status = {"right": 0, "left": 0, "flags": 3}
    body = {"serial_connected": True, "epoch": 7, "firmware_status": status}
    assert runner._unacknowledged(body, state, 100.5) is None
    fault = runner._unacknowledged(body, state, 101.2)
    assert fault is not None and fault[0] == "no_ack" and "watchdog" in fault[1]
    assert runner._unacknowledged({**body, "firmware_status": {"right": 1, "left": 1, "flags": 1}},
                                  state, 101.2) is None
    missing = runner._unacknowledged({**body, "firmware_status": None}, state, 101.2)
    assert missing is not None and "no status" in missing[1]
    assert TrialRunner.link_fault(body, epoch=7) is None
    reboot = TrialRunner.link_fault({**body, "epoch": 8}, epoch=7)
    assert reboot is not None and reboot[0] == "firmware_reboot"


def test_that_trial_run_drives_with_plan_and_records_its_name() -> None:
    import argparse

    from tumblebot.host.commands import _trial_policy
    from tumblebot.sim.control.goto import GotoPolicy

    args = argparse.Namespace(gait="plan", policy=None, steps=20, seed=0)
    policy, recorded = _trial_policy(args, None, "nav-flat")  # goto and plan do not need the design
    assert isinstance(policy, GotoPolicy) and recorded == "plan"
    assert policy.controller.config.memory == 0.25 and policy.controller.config.spin_steps_left == 3
