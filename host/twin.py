"""The digital twin: the whole deployed stack against the simulator and the real firmware.

Four processes talk over the lab's own links::

    world (this module) --UDP pose stream--> host (tumblebot trial run: controller, logs)
       ^      |                                   |
       |   firmware in simavr <--serial/pty-- Pi agent <--UDP commands--
       +-- servo pulses measured on pins D9/D10

The world process steps PyBullet in real time at 240 Hz, publishes the robot's pose like
a mocap system (100 Hz UDP pose stream), and drives the legs from the servo pulse widths
the emulated firmware puts on its pins, with the servos' physical mounting (the left one
mirrored). Nothing between the pose stream and the pins is a test double: the host, the
agent and the firmware are the production code. So a wrong frame transform, servo
direction or timing shows up as a gap between the twin's setpoint errors and those of a
pure-simulation evaluation from the same start points (:func:`consistency`).
"""

from __future__ import annotations

import json
import math
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.errors import TumblebotError
from tumblebot.host.link import free_port
from tumblebot.host.mocap import encode_pose_datagram
from tumblebot.pi_agent import protocol as P
from tumblebot.sim.control.gaits import GAITS
from tumblebot.sim.evaluation.evaluate import episode_seed
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.physics import PhysicsProfile

REPO = Path(__file__).resolve().parents[1]
NEUTRAL_US, FULL_SPEED_US = float(P.NEUTRAL_US), float(P.FULL_SPEED_US)  #: the firmware's pulses (µs)
DEADBAND_US = 10.0  #: continuous-rotation servos do not move within a few µs of neutral
#: Physical servo mounting: the right servo turns its leg forward for longer pulses; the
#: left one is mounted mirrored.
MOUNTING = {"right": +1.0, "left": -1.0}
SERVO_FRAME_S = 0.020  #: the firmware's servo frame: both pins' new widths start in the same frame
LATE_SUBSTEPS = 10  #: 42 ms at 240 Hz: the most the world may fall behind before a substep counts as late


class TwinError(TumblebotError):
    """The twin cannot run (no source checkout, no AVR toolchain or simavr)."""


def _emulator() -> Any:
    try:
        import serial  # noqa: F401  (the emulator and the agent need pyserial)
    except ModuleNotFoundError:
        raise TwinError("the twin runs the Pi agent and the emulated firmware: install tumblebot[agent] "
                        "(pyserial) as well as tumblebot[host]") from None
    from tumblebot.host import emulator

    if not (REPO / "firmware" / "arduino" / "Makefile").exists():
        raise TwinError("the twin builds the firmware from a source checkout; this install has none")
    return emulator


def pulse_to_command(width: float | None, mounting: float, neutral: float = NEUTRAL_US) -> float:
    """A servo's pulse width (µs) → its leg's command in [-1, 1] (no pulse: stopped).
    ``neutral`` is the servo's own neutral: a trim that differs from it makes the leg creep."""
    if width is None:
        return 0.0
    offset = width - neutral
    if abs(offset) < DEADBAND_US:
        return 0.0
    return max(-1.0, min(1.0, mounting * offset / FULL_SPEED_US))


def _start_emulator(serial_link: Path) -> Any:
    """The firmware in simavr, paced in real time, with ``serial_link`` pointing at its pty."""
    emulator = _emulator()
    try:
        emulator.build()
    except (subprocess.CalledProcessError, FileNotFoundError) as exc:
        raise TwinError(f"cannot build the firmware and the simavr harness ({exc}); ./dev.sh test installs "
                        "the AVR toolchain and simavr") from None
    uno = emulator.EmulatedUno(paced=True)
    if serial_link.is_symlink() or serial_link.exists():
        serial_link.unlink()
    serial_link.symlink_to(uno.pty)
    return uno


@dataclass(frozen=True)
class ServoHardware:
    """How the world's servos are built and mounted: their own neutral pulse (µs) and
    which way a longer pulse turns the leg. A lab's servos differ from the firmware's
    default trims; the twin can be given such servos to test bring-up (``bench check``)."""

    neutral: tuple[float, float] = (NEUTRAL_US, NEUTRAL_US)  #: (right, left)
    mounting: tuple[float, float] = (MOUNTING["right"], MOUNTING["left"])

    def commands(self, widths: tuple[float | None, float | None]) -> tuple[float, float]:
        return (pulse_to_command(widths[0], self.mounting[0], self.neutral[0]),
                pulse_to_command(widths[1], self.mounting[1], self.neutral[1]))


class _World:
    """The world's state between control datagrams and physics substeps."""

    def __init__(self, env: Any, uno: Any, pose_to: tuple[str, int], body: str, pose_rate: float,
                 hardware: ServoHardware) -> None:
        self.env, self.uno, self.pose_to, self.body = env, uno, pose_to, body
        self.hardware = hardware
        self.out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.dt = 1.0 / env.physics_hz
        self.pose_every = max(1, round(env.physics_hz / pose_rate))
        self.placed = False
        self.command = (0.0, 0.0)  #: the legs' commands now (right, left)
        self.pulses = (0.0, 0.0)  #: what the servo pulses on the pins command now
        #: (substep, command) not yet in force: a hidden world's command latency
        self.pending: list[tuple[int, tuple[float, float]]] = []
        self.latency_rng = np.random.default_rng(0x7A1E)
        #: (substep, delay) of the last latency draw: the firmware's two pins may change in
        #: different reads of one servo frame, and they carry one command, which the radio
        #: delays as a whole (as a replay does): changes within a frame share the draw
        self.burst: tuple[int, int] | None = None
        self.frame_substeps = max(1, round(SERVO_FRAME_S / self.dt))
        self.publish = {"on": True}  #: mocap on/off: the twin can simulate a tracking dropout
        # seq never goes back, across restarts of the world too (a signed stream requires it):
        # milliseconds since the epoch at start, then one per frame (at most 1000 frames a second)
        self.seq, self.sim_time, self.substeps = int(time.time() * 1000), 0.0, 0
        self.pose_key: bytes | None = None  #: sign the poses with this key
        self.dropped = 0  #: substeps skipped because the world fell behind real time
        self.late = 0  #: substeps simulated more than ``LATE_SUBSTEPS`` behind real time
        self.wall0 = time.monotonic()
        self.emulator_lag = (0.0, 0.0)  #: least and most (wall − firmware) seconds seen, from the first
        self._emulator_origin: tuple[float, int] | None = None

    def control(self, ctl: socket.socket, seed: int) -> bool:
        """Answer one control datagram; True on ``quit``."""
        data, source = ctl.recvfrom(4096)
        reply = _control(self.env, data, seed, self.uno, self.publish)
        if reply.pop("placed", False):
            self.placed, self.wall0, self.substeps, self.sim_time = True, time.monotonic(), 0, 0.0
            self.command = self.pulses = (0.0, 0.0)
            self.pending.clear()
            self.burst = None
            print(f"placed: {data.decode(errors='replace')}", file=sys.stderr, flush=True)
        quit_now = bool(reply.pop("quit", False))
        ctl.sendto(json.dumps(reply).encode(), source)
        return quit_now

    def _legs(self, command: tuple[float, float]) -> None:
        if command != self.command:  # the world's log: when the legs changed, to replay a trial exactly
            self.command = command
            print(f"legs {command[0]!r} {command[1]!r} from substep {self.substeps}", file=sys.stderr,
                  flush=True)  # every digit: a replay that rounds the speeds drifts apart (chaos)
        self.env.set_leg_commands(*command)

    def _track_emulator(self) -> None:
        """How far the emulated firmware's clock drifts behind real time (simavr is paced
        to real time, but cannot keep up on a starved machine)."""
        now, sim_us = time.monotonic(), self.uno.sim_us
        if self._emulator_origin is None:
            self._emulator_origin = (now, sim_us)
            return
        lag = (now - self._emulator_origin[0]) - (sim_us - self._emulator_origin[1]) / 1e6
        self.emulator_lag = (min(self.emulator_lag[0], lag), max(self.emulator_lag[1], lag))

    def catch_up(self) -> bool:
        """Simulate the substeps real time has made due (at most 24 at once: if the host
        stalls, do not race to catch up), under the servo pulses on the pins now,
        publishing mocap poses on the way. False when none was due."""
        due = int((time.monotonic() - self.wall0) / self.dt)
        if due <= self.substeps:
            return False
        self._track_emulator()
        command = self.hardware.commands(self.uno.widths())
        if command != self.pulses:  # a hidden world's latency delays it (none by default)
            self.pulses = command
            if self.burst is None or self.substeps - self.burst[0] > self.frame_substeps:
                lo, hi = self.env.randomization.latency
                self.burst = (self.substeps, round(self.latency_rng.uniform(lo, hi) / self.dt))
            self.pending.append((self.substeps + self.burst[1], command))
        behind = due - self.substeps
        self.late += max(0, min(behind, 24) - LATE_SUBSTEPS)
        for _ in range(min(behind, 24)):
            while self.pending and self.pending[0][0] <= self.substeps:
                self._legs(self.pending.pop(0)[1])
            self.env.advance(1)
            self.substeps += 1
            self.sim_time += self.dt
            if self.substeps % self.pose_every == 0 and self.publish["on"]:
                position, quaternion = self.env.base_pose()
                self.seq += 1
                self.out.sendto(encode_pose_datagram(self.body, self.seq, self.sim_time, position, quaternion,
                                                     key=self.pose_key),
                                self.pose_to)
        if due - 24 > self.substeps:
            self.dropped += due - 24 - self.substeps
            self.substeps = due - 24
        return True


def run_world(pose_to: tuple[str, int], control: tuple[str, int], serial_link: Path, design: Design, seed: int,
              body: str = "tumbler", pose_rate: float = 100.0, servo: PhysicsProfile | None = None,
              hardware: ServoHardware | None = None, physics: PhysicsProfile | None = None,
              pose_key: bytes | None = None) -> int:
    """The world process: real-time physics, mocap out, servo pulses in. Runs until
    SIGTERM/SIGINT or a ``quit`` control datagram. ``physics``: a world the rest of the
    stack is not told about (its servo, floor, extra radio latency and motor noise),
    instead of ``servo``."""
    uno = _start_emulator(serial_link)
    env = world_env(design, servo, physics)
    ctl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ctl.bind(control)
    ctl.setblocking(False)
    world = _World(env, uno, pose_to, body, pose_rate, hardware or ServoHardware())
    world.pose_key = pose_key
    stop = {"now": False}

    def on_signal(signum: int, frame: Any) -> None:
        stop["now"] = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    print(f"@ready pty={uno.pty} control={control[0]}:{control[1]}", flush=True)
    try:
        while not stop["now"]:
            readable, _, _ = select.select([ctl], [], [], 0.0)
            if readable and world.control(ctl, seed):
                stop["now"] = True
            if not world.placed:
                time.sleep(0.005)
            elif not world.catch_up():
                time.sleep(0.0005)
    finally:
        print(f"world: {world.dropped} substeps ({world.dropped * world.dt:.2f} s) dropped behind real time, "
              f"{world.late} of {world.substeps} simulated late; "
              f"firmware clock drift {world.emulator_lag[0]:+.3f}..{world.emulator_lag[1]:+.3f} s",
              file=sys.stderr, flush=True)
        env.close()
        uno.close()
        ctl.close()
        world.out.close()
        if serial_link.is_symlink():
            serial_link.unlink()
    return 0


def world_env(design: Design, servo: PhysicsProfile | None, physics: PhysicsProfile | None) -> Any:
    """The twin world's environment: under a hidden ``physics`` profile (its latency on top
    of the chain's own), or else under ``servo`` with no latency added (the chain is the
    latency). ``reports/twin-gap/replay.py`` rebuilds trials in the same one."""
    if physics is not None:  # a hidden world: its latency comes on top of the chain's own
        return physics.make_env("nav-flat", design=design)
    # The chain itself (agent, serial, firmware, servo frames) is the latency: none is added.
    return replace(servo or PhysicsProfile(), latency=(0.0, 0.0)).make_env("nav-flat", design=design)


def _control(env: Any, data: bytes, seed: int, uno: Any, publish: dict[str, bool]) -> dict[str, Any]:
    """One control datagram: ``place`` (a trial's start), ``mocap`` (``on``: true/false, to
    simulate losing tracking), ``status`` (the servo pulse widths on the pins), ``quit``."""
    try:
        msg = json.loads(data)
        if msg.get("cmd") == "mocap":
            publish["on"] = bool(msg["on"])
            return {"ok": True}
        if msg.get("cmd") == "status":
            right, left = uno.widths()
            return {"ok": True, "widths": [right, left], "mocap": publish["on"]}
        if msg.get("cmd") == "place":
            trial = int(msg["trial"])
            x, y, yaw = float(msg["x"]), float(msg["y"]), float(msg["yaw"])
            if not all(math.isfinite(v) for v in (x, y, yaw)) or trial < 0:
                raise ValueError("non-finite start")
            env.reset(seed=episode_seed(seed, trial), options={"start_xy": (x, y), "start_yaw": yaw})
            env.set_leg_commands(0.0, 0.0)
            publish["on"] = True
            return {"ok": True, "placed": True}
        if msg.get("cmd") == "quit":
            return {"ok": True, "quit": True}
        return {"ok": False, "error": f"unknown command {msg.get('cmd')!r}"}
    except (ValueError, KeyError, TypeError, json.JSONDecodeError) as exc:
        return {"ok": False, "error": f"bad control datagram: {exc}"}


# ----------------------------------------------------------------------------- orchestration
class TwinStack:
    """Starts the world and the agent as processes; the host is run against them."""

    def __init__(self, workdir: Path, design: Design, seed: int, servo: PhysicsProfile | None = None,
                 world_args: list[str] | None = None) -> None:
        from tumblebot.host.link import new_key

        servo = servo or PhysicsProfile()
        self.workdir = workdir
        self.key = workdir / "agent.key"
        new_key(self.key)
        self.pose_port, self.control_port, self.agent_port = free_port(), free_port(), free_port()
        self.serial_link = workdir / "ttyTWIN"
        self.agent_config = workdir / "agent.toml"
        self.agent_config.write_text(
            f'serial_port = "{self.serial_link}"\nbind_address = "127.0.0.1"\nbind_port = {self.agent_port}\n'
            f'allowed_host = "127.0.0.1"\nkey_file = "{self.key}"\n')
        self.agent: subprocess.Popen[bytes] | None = None
        self.world_log = (workdir / "world.log").open("w")
        servo.write(workdir / "world-physics.json")
        self.world = subprocess.Popen(
            [sys.executable, "-m", "tumblebot.cli", "twin", "world", "--pose-to", f"127.0.0.1:{self.pose_port}",
             "--control", f"127.0.0.1:{self.control_port}", "--serial-link", str(self.serial_link),
             "--design", ",".join(map(str, design.as_tuple())), "--seed", str(seed),
             "--physics", str(workdir / "world-physics.json"), "--pose-key", str(self.key), *(world_args or [])],
            stdout=subprocess.PIPE, stderr=self.world_log, text=True)
        assert self.world.stdout is not None
        line = self.world.stdout.readline()
        if not line.startswith("@ready"):
            self.close()
            tail = (workdir / "world.log").read_text().strip().splitlines()[-3:]
            raise TwinError("the world process did not start: " + (" | ".join(tail) or "no output"))
        self.start_agent()

    def start_agent(self) -> None:
        self.agent_log = (self.workdir / "agent.log").open("a")
        self.agent = subprocess.Popen([sys.executable, "-m", "tumblebot.pi_agent.agent", "--config",
                                       str(self.agent_config)], stdout=self.agent_log, stderr=subprocess.STDOUT)

    def kill_agent(self) -> None:
        if self.agent is not None:
            self.agent.kill()
            self.agent.wait()
            self.agent = None

    @property
    def mocap_url(self) -> str:
        """The twin's pose stream as the host reads it: signed with the stack's key."""
        return f"udp://127.0.0.1:{self.pose_port}?body=tumbler&key={self.key}"

    def host_args(self) -> list[str]:
        return ["--mocap", self.mocap_url, "--agent",
                f"127.0.0.1:{self.agent_port}", "--key", str(self.key), "--twin", f"127.0.0.1:{self.control_port}"]

    def close(self) -> None:
        self.kill_agent()
        if self.world.poll() is None:
            self.world.send_signal(signal.SIGTERM)
            try:
                self.world.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.world.kill()
                self.world.wait()
        self.world_log.close()

    def __enter__(self) -> TwinStack:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_twin(out: Path, points: int, per_point: int, radius: float, setpoint: tuple[float, float], heading: float,
             design: Design, seed: int, policy: str, extra: list[str] | None = None,
             servo: PhysicsProfile | None = None, world_physics: Path | None = None) -> int:
    """Run a trial set through the twin (the host as its own process). Returns its exit code.
    The world's servo (or hidden physics profile, ``world_physics``) is recorded in
    ``OUT/twin.json``, so :func:`consistency` simulates under the same world; nothing the
    host runs reads that record."""
    servo = servo or PhysicsProfile()
    physics = PhysicsProfile.load(str(world_physics)) if world_physics is not None else None
    world_args = ["--world-physics", str(world_physics)] if world_physics is not None else None
    with tempfile.TemporaryDirectory(prefix="tumblebot-twin-") as tmp, \
            TwinStack(Path(tmp), design, seed, servo, world_args) as stack:
        cmd = [sys.executable, "-m", "tumblebot.cli", "trial", "run", "--out", str(out), "--points", str(points),
               "--per-point", str(per_point), "--radius", str(radius), "--setpoint", f"{setpoint[0]},{setpoint[1]}",
               "--heading", str(heading), "--design", ",".join(map(str, design.as_tuple())), "--seed", str(seed),
               *(["--gait", policy] if policy in GAITS else ["--policy", policy]), *stack.host_args(),
               *(extra or [])]
        code = subprocess.run(cmd, check=False, env={**os.environ, "PYTHONUNBUFFERED": "1"}).returncode
        stack.close()  # the world writes how far it fell behind real time as it stops
        logs = {name: (Path(tmp) / name).read_text() for name in ("world.log", "agent.log")
                if (Path(tmp) / name).is_file()}
        if out.is_dir():
            record: dict[str, Any] = {"servo": servo.record()}
            if physics is not None:
                record["world_physics"] = {**physics.to_json(), "digest": physics.digest()}
            (out / "twin.json").write_text(json.dumps(record) + "\n")
            for name, text in logs.items():
                (out / f"twin-{name}").write_text(text)
        timing = [line for line in logs.get("world.log", "").splitlines() if line.startswith("world:")]
        if timing:
            print(timing[-1], flush=True)  # how well this machine kept the twin in real time
        return code


def twin_servo(folder: Path) -> PhysicsProfile:
    """The servo a twin trial set's world ran (the default for sets made before it was recorded)."""
    path = folder / "twin.json"
    if not path.is_file():
        return PhysicsProfile()
    try:
        return PhysicsProfile.from_card(json.loads(path.read_text()).get("servo") or {})
    except (ValueError, AttributeError) as exc:
        raise TwinError(f"{path} is not a twin record: {exc}") from None


def twin_world_physics(folder: Path) -> PhysicsProfile | None:
    """The hidden physics profile a twin trial set's world ran, if it had one."""
    path = folder / "twin.json"
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text()).get("world_physics")
    except (ValueError, AttributeError) as exc:
        raise TwinError(f"{path} is not a twin record: {exc}") from None
    if data is None:
        return None
    return PhysicsProfile.from_json({k: v for k, v in data.items() if k != "digest"}, str(path))


# ----------------------------------------------------------------------------- consistency
def simulate_starts(folder: Path, episodes_per_trial: int = 16, physics: PhysicsProfile | None = None
                    ) -> dict[str, Any]:
    """Pure-simulation final errors from the trial set's own start points and headings.

    For each finished trial: the same start point and yaw, expressed in the task frame,
    with ``episodes_per_trial`` episode seeds (the trial's own first), through
    ``TumblerEnv.step`` and the set's controller (its ONNX policy, or goto) under the
    twin's servo (or its hidden world, or ``physics`` if given: a calibrated profile's
    prediction): what ``tumblebot evaluate`` does, from these starts. ``per_trial`` holds
    the final errors grouped by trial, in the index's order.
    """
    from tumblebot.host.trial_sets import TrialPlan, load_index
    from tumblebot.sim.control.goto import NAVIGATORS
    from tumblebot.sim.evaluation.rollout import make_actor, run_episode
    from tumblebot.sim.world.frames import to_task_frame, yaw_quaternion

    plan = TrialPlan.from_json(json.loads((folder / "plan.json").read_text()))
    index = load_index(folder)
    kind = "goto" if plan.policy in NAVIGATORS else "onnx"
    actor = make_actor(kind, plan.policy, plan.task)
    physics = physics or twin_world_physics(folder)
    env = (physics if physics is not None else twin_servo(folder)).make_env(plan.task, design=Design(*plan.design))
    per_trial: list[list[float]] = []
    try:
        for entry in index["trials"]:
            per_trial.append([])
            trial = entry["trial"]
            yaw_lab = plan.start_yaw(trial)
            pos, quat = to_task_frame((*entry["start"], 0.0), yaw_quaternion(yaw_lab), plan.setpoint, plan.heading)
            yaw_task = 2 * math.atan2(quat[2], quat[3])
            for j in range(episodes_per_trial):
                s = episode_seed(plan.seed, trial) if j == 0 else episode_seed(plan.seed + 1_000_003 * j, trial)
                outcome = run_episode(env, actor, s, options={"start_xy": (float(pos[0]), float(pos[1])),
                                                              "start_yaw": yaw_task})
                fx, fy = outcome.final_position[:2]
                per_trial[-1].append(math.hypot(fx, fy))
    finally:
        env.close()
    return {"per_trial": per_trial, "episodes_per_trial": episodes_per_trial}


def upper_tail_p(twin_error: float, sim_errors: list[float] | np.ndarray) -> float:
    """How unusually *large* a twin trial's error is among pure-simulation errors from the
    same start: ``(1 + #{sim ≥ twin}) / (n + 1)``. Under consistency the twin error is one
    more draw of the same distribution, so this p-value is exactly uniform on
    ``{1/(n+1), …, 1}`` whatever that distribution's shape (errors are right-skewed: a few
    episodes end far away, which is what broke a test of means)."""
    sim = np.asarray(sim_errors, dtype=float)
    return float((1 + np.count_nonzero(sim >= twin_error)) / (len(sim) + 1))


def combined_p(p_values: list[float], sizes: list[int], draws: int = 200_000, seed: int = 0) -> float:
    """Fisher's combination ``S = −Σ ln p_i`` of per-trial :func:`upper_tail_p` values, with
    its exact null distribution (each ``p_i`` uniform on ``{1/(n_i+1), …, 1}``, independent):
    enumerated when small, else by Monte Carlo with ``draws`` samples. Small when the twin's
    errors sit in the upper tails of their starts' simulations again and again."""
    stat = -float(np.sum(np.log(p_values)))
    support = [-np.log(np.arange(1, n + 2) / (n + 1)) for n in sizes]
    combos = int(np.prod([len(s) for s in support], dtype=float))
    if combos <= 2_000_000:
        total = np.zeros(1)
        for values in support:  # all sums, with multiplicity
            total = (total[:, None] + values[None, :]).ravel()
        return float(np.mean(total >= stat - 1e-12))
    rng = np.random.default_rng(seed)
    sums = np.zeros(draws)
    for values in support:
        sums += values[rng.integers(len(values), size=draws)]
    return float((1 + np.count_nonzero(sums >= stat - 1e-12)) / (draws + 1))


def consistency_test(twin_errors: list[float] | np.ndarray, sim_per_trial: list[list[float]],
                     alpha: float = 0.01) -> dict[str, Any]:
    """The twin is NOT CONSISTENT when its errors are too large for their own starts'
    simulations: :func:`combined_p` below ``alpha``. One-sided on purpose: a frame,
    servo-direction or timing bug sends the robot away from the setpoint, never closer;
    a twin *better* than simulation is no alarm (it was one, by chance, under the old
    test of means). The false-alarm rate is at most ``alpha`` by construction (exact
    null distribution), for any number of trials and any error distribution."""
    twin = np.asarray(twin_errors, dtype=float)
    if len(twin) != len(sim_per_trial) or len(twin) == 0:
        raise TwinError("need one group of simulated errors per twin trial")
    ps = [upper_tail_p(t, s) for t, s in zip(twin, sim_per_trial, strict=True)]
    p = combined_p(ps, [len(s) for s in sim_per_trial])
    sim = np.concatenate([np.asarray(s, dtype=float) for s in sim_per_trial])
    return {"twin_mean_error": float(twin.mean()), "twin_median_error": float(np.median(twin)),
            "twin_n": len(twin), "sim_mean_error": float(sim.mean()), "sim_median_error": float(np.median(sim)),
            "sim_n": len(sim), "gap": float(twin.mean() - sim.mean()), "trial_p": ps, "p": p, "alpha": alpha,
            "test": "per-start upper-tail ranks, Fisher-combined, exact null", "consistent": bool(p >= alpha)}


def consistency(folder: Path, episodes_per_trial: int = 16, alpha: float = 0.01) -> dict[str, Any]:
    """Are the twin's setpoint errors consistent with pure simulation from the same starts?
    See :func:`consistency_test`."""
    from tumblebot.host.trial_sets import summarize

    twin = summarize(folder).errors
    sim = simulate_starts(folder, episodes_per_trial)
    return consistency_test(twin, sim["per_trial"], alpha)
