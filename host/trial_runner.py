"""The controller: mocap pose → task frame → ONNX policy → speed command, once a period.

One trial is ``steps`` decisions ``period`` s apart (thesis: 20 × 1 s). A decision is made
on the first accepted pose that arrives once it is due, so its latency is measured from
that frame's arrival to the command datagram leaving. Between decisions the current
command is resent every ``keepalive`` s (the agent stops the robot after 1 s without a
valid datagram, the firmware after 250 ms without a frame from the agent).

The robot is stopped, and the trial ends with the reason, when tracking is lost (no
accepted pose for ``lost_after`` s), when the agent stops answering telemetry requests
(``agent_timeout`` s), on Ctrl-C, and after the last decision.

A trial also ends, and is never recorded as finished, when the agent's telemetry shows
that the robot cannot have done what it was told (:meth:`TrialRunner.link_fault`):

* ``serial_lost``: the agent has no serial link to the Arduino (the USB cable is out, or
  the board does not answer). A trial does not start without one.
* ``firmware_reboot``: the firmware's epoch changed mid-trial (the Uno reset: a brown-out,
  a loose supply, a reflash).
* ``no_ack``: a command has been in force for ``ack_timeout`` s but the firmware's status
  reports other speeds (its watchdog holds the servos, or the frames never arrive), or
  no status at all.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tumblebot.errors import TumblebotError
from tumblebot.host.link import AgentClient
from tumblebot.host.mocap import Pose, PoseFilter, PoseSource
from tumblebot.host.triallog import BackgroundLog, TrialLogWriter
from tumblebot.sim.world.frames import to_task_frame

COMPLETE = "complete"


@dataclass
class _TrialState:
    """Where a running trial stands (times from ``time.monotonic``)."""

    start: float
    end: float  #: when the last decision's period is over
    next_decision: float
    decisions: int = 0
    last_sent: float = -1e9  #: when a command last left (keepalives follow it)
    fresh: Pose | None = None  #: the newest pose
    latencies: list[float] = field(default_factory=list)
    times: list[tuple[float, float | None, float]] = field(default_factory=list)
    epoch: int | None = None  #: the firmware's epoch when the trial started
    command_since: float = 0.0  #: when the command in force was first sent

    @classmethod
    def starting(cls, now: float, config: ControllerConfig, epoch: int | None = None) -> _TrialState:
        return cls(start=now, end=now + config.steps * config.period, next_decision=now, epoch=epoch,
                   command_since=now)


class ControllerError(TumblebotError):
    """A controller configuration that cannot work (a non-positive period, no steps, …)."""


@dataclass(frozen=True)
class ControllerConfig:
    period: float = 1.0  #: s between decisions (the policy was trained at 1 Hz)
    steps: int = 20  #: decisions per trial
    keepalive: float = 0.2  #: s between resends of the current command
    lost_after: float = 0.5  #: s without an accepted pose = tracking lost
    agent_timeout: float = 1.5  #: s without telemetry from the agent = agent lost
    telemetry_every: float = 0.25  #: s between telemetry requests
    max_speed: float = 3.0  #: m/s; faster pose jumps are outliers
    first_pose_timeout: float = 3.0  #: s to wait for tracking at the start
    #: s a command may be in force before the firmware's status must show it (the agent asks
    #: the Arduino for its status once a second)
    ack_timeout: float = 2.5

    def __post_init__(self) -> None:
        for name in ("period", "keepalive", "lost_after", "agent_timeout", "telemetry_every", "max_speed",
                     "first_pose_timeout", "ack_timeout"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ControllerError(f"controller {name}={value!r} must be a positive number")
        if self.steps < 1:
            raise ControllerError(f"controller steps={self.steps} must be at least 1")


@dataclass
class TrialResult:
    #: complete, mocap_lost, agent_lost, no_mocap, serial_lost, firmware_reboot, no_ack, interrupted
    status: str
    reason: str
    decisions: int
    final_position: tuple[float, float, float] | None = None
    final_error: float | None = None  #: planar distance to the setpoint at the end, m
    latencies_ms: list[float] = field(default_factory=list)
    #: per decision: (pose arrival, pose source timestamp, command sent), monotonic s
    decision_times: list[tuple[float, float | None, float]] = field(default_factory=list)
    stop_latency: float | None = None  #: s from the cause of an abort to the STOP datagram

    def to_json(self) -> dict[str, Any]:
        return {"status": self.status, "reason": self.reason, "decisions": self.decisions,
                "final_position": self.final_position, "final_error": self.final_error,
                "stop_latency": self.stop_latency}


class TrialRunner:
    """Runs trials of one policy toward one setpoint.

    Args:
        source: where poses come from (:func:`tumblebot.host.mocap.open_source`).
        agent: the link to the Pi agent.
        policy: anything with ``act(obs) -> (a_right, a_left)`` in {0, 1, 2}; its
            ``reset()``, if it has one, is called at the start of every trial (an
            :class:`~tumblebot.sim.control.policy.OnnxPolicy` conditioned on the design is bound
            to it first, :meth:`~tumblebot.sim.control.policy.OnnxPolicy.bind_design`).
        setpoint: lab-frame goal ``(x, y)``; heading: lab-frame direction (rad) that
            becomes the task frame's +x.
    """

    def __init__(self, source: PoseSource, agent: AgentClient, policy: Any, setpoint: tuple[float, float],
                 heading: float = 0.0, config: ControllerConfig | None = None) -> None:
        self.source, self.agent, self.policy = source, agent, policy
        self.setpoint, self.heading = setpoint, heading
        self.config = config or ControllerConfig()
        self.filter = PoseFilter(self.config.max_speed, self.config.lost_after)
        self.command = (0, 0)

    # ------------------------------------------------------------------ pieces
    def observation(self, pose: Pose) -> np.ndarray:
        position, quaternion = to_task_frame(pose.position, pose.quaternion, self.setpoint, self.heading)
        return np.array([*position, *quaternion, *self.command], dtype=np.float32)

    def distance(self, pose: Pose) -> float:
        return math.hypot(pose.position[0] - self.setpoint[0], pose.position[1] - self.setpoint[1])

    def pump(self, timeout: float, log: TrialLogWriter | BackgroundLog | None, defer_log: bool = False) -> list[Pose]:
        """Read the source; accepted poses are returned, and logged unless ``defer_log``
        (the trial loop decides first and logs after the command has left)."""
        accepted = [pose for pose in self.source.poll(timeout) if self.filter.offer(pose)]
        if log is not None and not defer_log:
            for pose in accepted:
                log.write("/pose", pose.to_json())
        return accepted

    def drain(self) -> int:
        """Discard every pose waiting in the source; returns how many."""
        n = 0
        while True:
            poses = self.source.poll(0.0)
            if not poses:
                return n
            n += len(poses)

    def wait_for_tracking(self, timeout: float, log: TrialLogWriter | BackgroundLog | None = None) -> Pose | None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.pump(0.05, log)
            if self.filter.last is not None and not self.filter.lost(time.monotonic()):
                return self.filter.last
        return None

    def stop_robot(self, log: TrialLogWriter | BackgroundLog | None, why: str) -> float:
        self.command = (0, 0)
        sent = self.agent.stop()
        if log is not None:
            log.write("/command", {"right": 0, "left": 0, "kind": f"stop: {why}"})
        return sent

    # ------------------------------------------------------------------ a trial
    def run_trial(self, log: TrialLogWriter | BackgroundLog | None = None,
                  on_status: Callable[[int, Pose | None, float], None] | None = None) -> TrialResult:
        """One trial. Always leaves the robot stopped (STOP is sent in ``finally``)."""
        self._begin_trial()
        result: TrialResult | None = None
        try:
            result = self._wait_for_tracking_and_agent(log)
            if result is not None:
                return result
            self._event(log, "start", f"setpoint {self.setpoint}, heading {self.heading:.3f} rad")
            state = _TrialState.starting(time.monotonic(), self.config, self.agent.last_telemetry.get("epoch"))
            while result is None:
                result = self._tick(state, log, on_status)
            return result
        except KeyboardInterrupt:
            self.stop_robot(log, "interrupted")
            self._event(log, "interrupted", "Ctrl-C")
            raise
        finally:
            for _ in range(3):  # the robot is stopped whatever happened; repeated in case one is lost
                self.agent.stop()
            if result is not None and result.status != COMPLETE:
                self._event(log, result.status, result.reason)

    def _begin_trial(self) -> None:
        """Forget the last trial's poses, drop poses queued while the robot was being placed
        (they show where it was, not where it is), and restart a controller with memory
        (goto, a context policy)."""
        self.command = (0, 0)
        self.filter = PoseFilter(self.config.max_speed, self.config.lost_after)
        self.drain()
        reset = getattr(self.policy, "reset", None)
        if callable(reset):
            reset()

    @staticmethod
    def _event(log: TrialLogWriter | BackgroundLog | None, name: str, detail: str = "") -> None:
        if log is not None:
            log.write("/event", {"event": name, "detail": detail})

    def _wait_for_tracking_and_agent(self, log: TrialLogWriter | BackgroundLog | None) -> TrialResult | None:
        """None once the robot is tracked and the agent answers; else why the trial cannot start."""
        cfg = self.config
        if self.wait_for_tracking(cfg.first_pose_timeout, log) is None:
            return TrialResult("no_mocap", f"no pose from {self.source.url} for {cfg.first_pose_timeout:.1f} s", 0)
        self.agent.request_telemetry()
        deadline = time.monotonic() + cfg.agent_timeout
        while not self.agent.poll():
            if time.monotonic() - self.agent.last_request_at >= cfg.telemetry_every:
                self.agent.request_telemetry()  # a request lost on the network is not a lost agent
            if time.monotonic() > deadline:
                return TrialResult("agent_lost", f"the agent at {self.agent.address[0]}:{self.agent.address[1]}"
                                   f" did not answer within {cfg.agent_timeout:.1f} s", 0)
            self.pump(0.02, log)
        fault = self.link_fault(self.agent.last_telemetry, sender=self.agent.sender)
        if fault is not None:
            return TrialResult(*fault, 0)
        return None

    @staticmethod
    def link_fault(body: dict[str, Any], epoch: int | None = None, sender: int | None = None
                   ) -> tuple[str, str] | None:
        """``(status, reason)`` if telemetry ``body`` says the robot cannot act on commands:
        no serial link to the Arduino, (given the trial's ``epoch``) a firmware reboot, or
        (given this host's ``sender`` id) another host in control."""
        controller = body.get("controller")
        if sender is not None and controller is not None and controller != sender:
            return ("taken_over", f"another host (sender {controller}) controls the robot: this one stops; run "
                    "with --take-over to take control back")
        if body.get("serial_connected") is not True:
            return ("serial_lost", "the agent has no serial link to the Arduino (telemetry says serial_connected: "
                    "false): check the USB cable between the Pi and the Uno, and the Uno's power")
        now_epoch = body.get("epoch")
        if epoch is not None and now_epoch != epoch:
            return ("firmware_reboot", f"the firmware rebooted during the trial (epoch {epoch} became {now_epoch}): "
                    "check the servo supply (a brown-out resets the Uno) and the USB cable")
        return None

    def _unacknowledged(self, body: dict[str, Any], state: _TrialState, now: float) -> tuple[str, str] | None:
        """``("no_ack", reason)`` if the command in force for ``ack_timeout`` s is not what the
        firmware reports running."""
        held = now - state.command_since
        if held < self.config.ack_timeout:
            return None
        status = body.get("firmware_status")
        if not isinstance(status, dict):
            return ("no_ack", f"the firmware has reported no status for {held:.1f} s of command {self.command}")
        running = (status.get("right"), status.get("left"))
        if running != self.command:
            holding = " (its watchdog holds the servos stopped)" if int(status.get("flags") or 0) & 2 else ""
            return ("no_ack", f"the firmware runs {running[0]}, {running[1]}{holding} but was commanded "
                    f"{self.command[0]}, {self.command[1]} {held:.1f} s ago")
        return None

    def _tick(self, state: _TrialState, log: TrialLogWriter | BackgroundLog | None,
              on_status: Callable[[int, Pose | None, float], None] | None) -> TrialResult | None:
        """One pass of the trial loop: take poses, decide when a decision is due, log after
        the command has left, then check how the trial stands. None while it goes on."""
        cfg = self.config
        now = time.monotonic()
        due = state.decisions < cfg.steps
        arrived = self.pump(min(0.02, max(0.0, state.next_decision - now)) if due else 0.02, log, defer_log=True)
        if arrived:
            state.fresh = arrived[-1]
        now = time.monotonic()
        decision = self._decide(state, now)
        if log is not None:  # after the command has left: logging never delays a decision
            for pose in arrived:
                log.write("/pose", pose.to_json())
            if decision is not None:
                log.write("/decision", decision)
                log.write("/command", {"right": self.command[0], "left": self.command[1], "kind": "policy"})
        if decision is not None and on_status is not None and state.fresh is not None:
            on_status(state.decisions, state.fresh, self.distance(state.fresh))
        result = self._verdict(state, now, log)
        if result is None and now - state.last_sent >= cfg.keepalive:
            state.last_sent = self.agent.command(*self.command)
        return result

    def _decide(self, state: _TrialState, now: float) -> dict[str, Any] | None:
        """Ask the policy and send its command, if a decision is due and a pose newer than
        its time has arrived; returns the decision's log record."""
        fresh = state.fresh
        if state.decisions >= self.config.steps or fresh is None or fresh.t < state.next_decision - 1e-3 \
                or now < state.next_decision - 1e-3:
            return None
        obs = self.observation(fresh)
        action = np.asarray(self.policy.act(obs)).reshape(-1)
        command = (int(action[0]) - 1, int(action[1]) - 1)
        if command != self.command:
            state.command_since = now
        self.command = command
        state.last_sent = self.agent.command(*self.command)
        latency = (state.last_sent - fresh.t) * 1e3
        state.latencies.append(latency)
        state.times.append((fresh.t, fresh.source_time, state.last_sent))
        decision = {"step": state.decisions, "t": state.last_sent, "observation": [float(v) for v in obs],
                    "command": list(self.command), "distance": self.distance(fresh), "latency_ms": latency}
        state.decisions += 1
        state.next_decision = state.start + state.decisions * self.config.period
        return decision

    def _verdict(self, state: _TrialState, now: float, log: TrialLogWriter | BackgroundLog | None
                 ) -> TrialResult | None:
        """The trial's end, if it has come: every decision made, the pose lost, or the agent
        silent (telemetry is asked for and logged on the way). None while it goes on."""
        cfg = self.config
        if state.decisions >= cfg.steps and now >= state.end:
            final = self.filter.last
            assert final is not None
            stop_sent = self.stop_robot(log, "end of trial")
            result = TrialResult(COMPLETE, "all decisions made", state.decisions, final.position,
                                 self.distance(final), state.latencies, state.times, stop_sent - now)
            self._event(log, "end", f"final error {result.final_error:.3f} m")
            return result
        if self.filter.lost(now):
            assert self.filter.last is not None
            lost_at = self.filter.last.t + cfg.lost_after
            stop_sent = self.stop_robot(log, "mocap lost")
            return TrialResult("mocap_lost", f"no pose for {self.filter.age(now):.2f} s", state.decisions,
                               latencies_ms=state.latencies, stop_latency=stop_sent - lost_at)
        if now - self.agent.last_request_at >= cfg.telemetry_every:
            self.agent.request_telemetry()
        for body in self.agent.poll():
            if log is not None:
                log.write("/telemetry", body)
            fault = self.link_fault(body, state.epoch, self.agent.sender) or self._unacknowledged(body, state, now)
            if fault is not None:
                stop_sent = self.stop_robot(log, fault[0])
                return TrialResult(*fault, state.decisions, latencies_ms=state.latencies,
                                   stop_latency=stop_sent - now)
        if self.agent.silent_for(now) > cfg.agent_timeout:
            stop_sent = self.stop_robot(log, "agent not answering")
            return TrialResult("agent_lost", f"no telemetry from the agent for {self.agent.silent_for(now):.1f} s",
                               state.decisions, latencies_ms=state.latencies,
                               stop_latency=stop_sent - (self.agent.last_telemetry_at + cfg.agent_timeout))
        return None
