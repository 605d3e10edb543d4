"""Bring-up at the bench: set a servo's trim, and check the robot before a trial set.

``tumblebot trim`` reads the trims the firmware holds (its INFO, relayed in the agent's
telemetry) and sets one servo's neutral pulse and direction: an authenticated SET_TRIM to
the agent, which forwards it to the Arduino only while the robot is stopped; the firmware
stores it in EEPROM and answers with the trims now in force, which is what is shown.

``tumblebot bench check`` answers, one line each, the questions to settle before a trial
set (:data:`CHECKS`): does the agent answer, is the Arduino connected (its boot epoch and
firmware version), which trims does it hold, does the motion capture see the robot with
the simulator's frame (z up while it lies flat), does the robot keep still when stopped
(a servo whose neutral trim is off creeps), does each servo turn both ways when told, and
do the legs stop when the host falls silent. Exit 0 only when every one holds.

How a servo's direction is seen from the poses: the legs turn about the body's x axis (the
leg axis), and a leg turning forward rolls the body about +x (it tumbles toward the body's
−y, which is forward), whatever the body's size; a leg turning in reverse rolls it about
−x. So the body's roll about its own x axis, summed over the poses while one servo is told
to turn, has the sign of the direction that servo really turned. In simulation, over the
design bounds, a servo told to turn for 2 s never rolled the body the wrong way by more
than 0.03 rad, while one that can lift the body rolls it 0.1–1.4 rad; a body that one leg
alone cannot lift shows no roll, and then the check says it cannot tell.
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tumblebot.errors import TumblebotError
from tumblebot.host.link import AgentClient
from tumblebot.host.mocap import Pose, PoseFilter, PoseSource
from tumblebot.pi_agent import protocol as P

SERVOS = P.SERVOS
CHECKS = ("agent", "arduino", "trims", "mocap", "still", "servos", "watchdog")
ANSWER_WAIT = 5.0  #: s to wait for the agent, and then for its serial link
TURN_SECONDS = 3.0  #: s each servo is told to turn, each way (a leg in the air needs up to a turn to reach the floor)
TURN_ATTEMPTS = 3  #: turns tried, each way, before a servo whose turn shows no roll is reported
SETTLE_SECONDS = 1.0  #: s stopped before each observation
STILL_SECONDS = 5.0  #: s the robot is watched while stopped
NOMINAL_NEUTRAL_US = P.NEUTRAL_US  #: the neutral pulse of a standard continuous-rotation servo (the firmware's default)
NEUTRAL_SPREAD_US = P.NEUTRAL_SPREAD_US  #: how far a trim may lie from nominal before it is an error
ROLL_SEEN = 0.1  #: rad of body roll that shows a leg turned (a turning leg that lifts the body rolls it more)
STILL_MOVE = 0.01  #: m a stopped robot may drift before it counts as creeping
STILL_TURN = 0.05  #: rad (about 3°) a stopped robot may turn before it counts as creeping
LEVEL_TOLERANCE = math.radians(15.0)  #: at rest the leg axis is this close to level, a face normal to up
#: A stopped tumbler may still settle onto a face; a driven one rolls more than 1 rad and
#: covers about 0.2 m a second: motion above these in one second means the legs still turn.
STOPPED_MOVE, STOPPED_TURN = 0.05, math.radians(20.0)
SILENCE_SECONDS = 2.5  #: s the host stays silent in the watchdog check (the agent stops after 1 s)


TRIM_DOC = "docs/robot-link.md, 'Trimming a servo'"
FRAME_DOC = "docs/robot-link.md, 'The motion-capture frame'"


class BenchError(TumblebotError):
    """A bench command cannot run (bad arguments, an agent that does not answer)."""


@dataclass
class Check:
    """One line of ``bench check``: ``ok`` is None when it could not be checked."""

    name: str
    ok: bool | None
    detail: str
    fix: str | None = None

    def line(self) -> str:
        mark = {True: "ok  ", False: "FAIL", None: "----"}[self.ok]
        text = f"{self.name:<9} {mark} {self.detail}"
        return text + (f"; {self.fix}" if self.fix else "")

    def to_json(self) -> dict[str, Any]:
        return {"check": self.name, "ok": self.ok, "detail": self.detail, "fix": self.fix}


# ----------------------------------------------------------------------------- pose geometry
def _rotation(q: tuple[float, ...] | np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``(x, y, z, w)``."""
    x, y, z, w = (float(v) for v in q)
    n = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _rotation_vector(r: np.ndarray) -> np.ndarray:
    """Axis × angle of a rotation matrix (angles below π, as between poses 10 ms apart)."""
    angle = math.acos(max(-1.0, min(1.0, (float(np.trace(r)) - 1.0) / 2.0)))
    if angle < 1e-9:
        return np.zeros(3)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / (2.0 * math.sin(angle))
    return axis * angle


def body_roll(poses: list[Pose]) -> float:
    """The body's rotation about its own x axis (the leg axis), summed over consecutive
    poses, in radians: positive when it tumbles forward (toward its −y)."""
    total = 0.0
    for a, b in itertools.pairwise(poses):
        relative = _rotation(a.quaternion).T @ _rotation(b.quaternion)  # b in a's body frame
        total += float(_rotation_vector(relative)[0])
    return total


def resting_frame(pose: Pose) -> tuple[float, str, float]:
    """How the body rests: the tilt of its x axis (the leg axis) from level (rad), the body
    face that points up (``+z``, ``-y``, …) and that face's normal's angle from up (rad).
    A tumbler on the floor rests on one of the four faces around its leg axis; lying flat
    (as the simulator spawns it) is ``+z`` up."""
    r = _rotation(pose.quaternion)
    level = math.asin(min(1.0, abs(float(r[2, 0]))))
    ups = {f"{sign}{axis}": math.acos(max(-1.0, min(1.0, (1 if sign == "+" else -1) * float(r[2, i]))))
           for i, axis in ((1, "y"), (2, "z")) for sign in "+-"}
    face = min(ups, key=lambda k: ups[k])
    return level, face, ups[face]


def motion(poses: list[Pose]) -> tuple[float, float]:
    """How far (m, planar) and how much (rad, any axis) the body moved from the first pose."""
    if len(poses) < 2:
        return 0.0, 0.0
    first = poses[0]
    r0 = _rotation(first.quaternion)
    moved = max(math.dist(p.position[:2], first.position[:2]) for p in poses)
    turned = max(float(np.linalg.norm(_rotation_vector(r0.T @ _rotation(p.quaternion)))) for p in poses)
    return moved, turned


# ----------------------------------------------------------------------------- the bench
@dataclass
class Bench:
    """The agent (and, with a pose source, the robot's poses) for bring-up."""

    agent: AgentClient
    source: PoseSource | None = None
    ask: Callable[[str], bool] | None = None  #: an operator's yes/no, or None with no operator
    say: Callable[[str], None] = print
    expected_neutral: tuple[int, int] | None = None  #: (right, left) µs, as the lab's trim procedure found them
    filter: PoseFilter = field(default_factory=PoseFilter)

    def where(self) -> str:
        return f"{self.agent.address[0]}:{self.agent.address[1]}"

    def telemetry(self, timeout: float = ANSWER_WAIT,
                  accept: Callable[[dict[str, Any]], bool] = lambda body: True) -> dict[str, Any] | None:
        return self.agent.telemetry_until(timeout, accept)

    def run(self, seconds: float, command: tuple[int, int] | None = (0, 0)) -> list[Pose]:
        """Hold ``command`` for ``seconds`` (keepalive every 0.2 s, telemetry every 0.5 s),
        collecting the poses; ``command=None`` sends nothing at all (the host falls silent)."""
        poses: list[Pose] = []
        end = time.monotonic() + seconds
        last_command = last_request = -1e9
        while (now := time.monotonic()) < end:
            if command is not None:
                if now - last_command >= 0.2:
                    last_command = now
                    self.agent.command(*command)
                if now - last_request >= 0.5:
                    last_request = now
                    self.agent.request_telemetry()
                self.agent.poll()
            if self.source is not None:
                poses += [p for p in self.source.poll(0.02) if self.filter.offer(p)]
            else:
                time.sleep(0.02)
        return poses

    def stop(self) -> list[Pose]:
        """Stop the legs and keep sending stop for 0.3 s; the poses of that time."""
        self.agent.stop()
        return self.run(0.3)


# ----------------------------------------------------------------------------- trim
def trims_of(body: dict[str, Any]) -> dict[str, dict[str, int]] | None:
    firmware = body.get("firmware")
    trims = firmware.get("trims") if isinstance(firmware, dict) else None
    if not isinstance(trims, dict) or set(trims) != set(SERVOS):
        return None
    try:
        return {name: {"neutral_us": int(trims[name]["neutral_us"]), "direction": int(trims[name]["direction"])}
                for name in SERVOS}
    except (KeyError, TypeError, ValueError):  # telemetry of an agent that is not this one's version
        return None


def format_trims(trims: dict[str, dict[str, int]]) -> str:
    return ", ".join(f"{name} {trims[name]['neutral_us']} µs {trims[name]['direction']:+d}" for name in SERVOS)


def read_trims(bench: Bench) -> dict[str, dict[str, int]]:
    """The trims the firmware holds, from the agent's telemetry (one error line if none)."""
    body = bench.telemetry(ANSWER_WAIT, lambda b: trims_of(b) is not None)
    if body is not None:
        trims = trims_of(body)
        assert trims is not None
        return trims
    last = bench.agent.last_telemetry
    if not last:
        raise BenchError(f"the agent at {bench.where()} did not answer within {ANSWER_WAIT:.0f} s "
                         "(is it running, with this key?)")
    if not last.get("serial_connected"):
        raise BenchError("the agent answers but has no serial link to the Arduino (USB cable? its log says why)")
    raise BenchError("the Arduino does not report its trims: flash firmware 1.1 or later (make -C firmware/arduino "
                     "flash)")


def set_trim(bench: Bench, servo: str, neutral_us: int | None = None, nudge_us: int | None = None,
             direction: int | None = None, timeout: float = ANSWER_WAIT) -> tuple[dict[str, int], dict[str, int]]:
    """Set one servo's trim; returns (before, after) as the firmware reports them."""
    index = SERVOS.index(servo)
    before = read_trims(bench)[servo]
    neutral = neutral_us if neutral_us is not None else before["neutral_us"] + (nudge_us or 0)
    sign = direction if direction is not None else before["direction"]
    try:
        P.check_trim(index, neutral, sign)
    except P.FrameError:
        raise BenchError(f"neutral {neutral} µs is outside {P.NEUTRAL_MIN_US}–{P.NEUTRAL_MAX_US} µs") from None
    wanted = {"neutral_us": neutral, "direction": sign}
    bench.stop()  # the agent forwards a trim only while the robot is stopped
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        bench.agent.set_trim(index, neutral, sign)
        body = bench.telemetry(min(1.0, max(0.0, deadline - time.monotonic())),
                               lambda b: (trims_of(b) or {}).get(servo) == wanted)
        if body is not None:
            return before, wanted
    drops = bench.agent.last_telemetry.get("drops", {})
    if drops.get("not_in_control"):
        raise BenchError(f"another host (sender {bench.agent.last_telemetry.get('controller')}) controls the robot: "
                         "pass --take-over to take control")
    raise BenchError(f"the firmware did not confirm the {servo} trim within {timeout:.0f} s "
                     f"(agent drops: {drops or 'none'}; is the robot stopped and the Arduino connected?)")


# ----------------------------------------------------------------------------- check
def _link_checks(bench: Bench) -> tuple[list[Check], dict[str, Any] | None]:
    started = time.monotonic()
    body = bench.telemetry(ANSWER_WAIT)
    if body is None:
        return [Check("agent", False, f"no answer from {bench.where()} within {ANSWER_WAIT:.0f} s",
                      "is the agent running, with this key, and this host its allowed_host?")], None
    waited = 1e3 * (time.monotonic() - started)
    controller = body.get("controller")
    if controller not in (None, bench.agent.sender):
        return [Check("agent", False, f"{bench.where()} answers, but another host (sender {controller}) controls "
                                      "the robot", "pass --take-over to take control")], None
    checks = [Check("agent", True, f"{bench.where()} answers (session and first telemetry in {waited:.0f} ms)")]
    body = bench.telemetry(ANSWER_WAIT, lambda b: bool(b.get("serial_connected")) and b.get("firmware") is not None)
    last = bench.agent.last_telemetry
    if body is None and not last.get("serial_connected"):
        checks.append(Check("arduino", False, f"not connected: the agent has had no serial link for "
                                              f"{ANSWER_WAIT:.0f} s", "check the USB cable; the agent's log says why"))
        return checks, None
    if body is None:
        checks.append(Check("arduino", False, f"connected (epoch {last.get('epoch')}) but its firmware never said "
                                              "its version", "flash firmware 1.1 or later: make -C firmware/arduino "
                                                             "flash"))
        return checks, None
    firmware = body["firmware"]
    checks.append(Check("arduino", True, f"connected: epoch {body.get('epoch')}, firmware {firmware.get('version')} "
                                         f"(protocol {firmware.get('protocol')})"))
    checks.append(_trim_check(trims_of(body), bench.expected_neutral))
    return checks, body


def _trim_check(trims: dict[str, dict[str, int]] | None, expected: tuple[int, int] | None) -> Check:
    """The neutral trims against the lab's (``expected``, found with the trim procedure) or,
    without them, against the nominal neutral: a servo's own neutral lies within
    :data:`NEUTRAL_SPREAD_US` of it, so a trim farther away makes that servo creep."""
    if trims is None:
        return Check("trims", False, "the firmware does not report its trims", "flash firmware 1.1 or later")
    off = []
    for i, servo in enumerate(SERVOS):
        neutral = trims[servo]["neutral_us"]
        if expected is not None and neutral != expected[i]:
            off.append(f"{servo} neutral is {neutral} µs, the lab's is {expected[i]} µs")
        elif expected is None and abs(neutral - NOMINAL_NEUTRAL_US) > NEUTRAL_SPREAD_US:
            off.append(f"{servo} neutral {neutral} µs is {neutral - NOMINAL_NEUTRAL_US:+d} µs off "
                       f"{NOMINAL_NEUTRAL_US} µs")
    if off:
        servo = off[0].split()[0]
        return Check("trims", False, f"{format_trims(trims)}: " + "; ".join(off) + " (that servo creeps when stopped)",
                     f"find its neutral ({TRIM_DOC}) and set it: "
                     f"tumblebot trim --servo {servo} --neutral US")
    against = "the lab's" if expected is not None else f"within ±{NEUTRAL_SPREAD_US} µs of nominal"
    return Check("trims", True, f"{format_trims(trims)} ({against})")


def _mocap_check(bench: Bench) -> Check:
    poses = bench.run(SETTLE_SECONDS)
    if not poses:
        bench.source = None  # nothing to measure with: the motion checks fall back to the operator
        return Check("mocap", False, f"no poses in {SETTLE_SECONDS:.0f} s",
                     "is the rigid body tracked, and named as in the URL's ?body=?")
    rate = (len(poses) - 1) / max(poses[-1].t - poses[0].t, 1e-3)
    level, face, tilt = resting_frame(poses[-1])
    fix = ("define the rigid body with x toward the right leg and z up when the robot lies flat "
           f"({FRAME_DOC})")
    if level > LEVEL_TOLERANCE:
        return Check("mocap", False, f"the rigid body's x axis is {math.degrees(level):.0f}° from level, but the "
                                     "robot's leg axis is level on the floor", fix)
    if tilt > LEVEL_TOLERANCE:
        return Check("mocap", False, f"the robot rests on no face of the rigid body's frame (the nearest, {face}, "
                                     f"is {math.degrees(tilt):.0f}° from up)", fix)
    flat = "lying flat: z up" if face == "+z" else f"resting on its side: {face} up"
    return Check("mocap", True, f"{len(poses)} poses at {rate:.0f} Hz; leg axis level ({math.degrees(level):.0f}°), "
                                f"{flat} ({math.degrees(tilt):.0f}°)")


def _wait_until_at_rest(bench: Bench, timeout: float = 5.0) -> None:
    """Watch half-second windows until one shows the body at rest (or ``timeout`` s pass)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        moved, turned = motion(bench.run(0.5))
        if moved < STILL_MOVE / 4 and turned < STILL_TURN / 4:
            return


def _still_check(bench: Bench) -> Check:
    fix = f"a servo creeps: its neutral trim is off; find it with tumblebot trim ({TRIM_DOC})"
    if bench.source is None:
        if bench.ask is None:
            return Check("still", None, "not checked: needs --mocap or an operator at a terminal")
        bench.say(f"Both legs should now be still for {STILL_SECONDS:.0f} s.")
        bench.run(STILL_SECONDS)
        if bench.ask("Were both legs still?"):
            return Check("still", True, "the operator saw both legs still")
        return Check("still", False, "the operator saw a leg move while stopped", fix)
    _wait_until_at_rest(bench)  # just put down (or placed by the twin): let it settle first
    poses = bench.run(STILL_SECONDS)
    moved, turned = motion(poses)
    detail = f"stopped for {STILL_SECONDS:.0f} s: moved {1e3 * moved:.0f} mm, turned {math.degrees(turned):.1f}°"
    if len(poses) < 2:
        return Check("still", None, "not checked: the poses stopped")
    if moved > STILL_MOVE or turned > STILL_TURN:
        return Check("still", False, detail, fix)
    return Check("still", True, detail)


def _turn(bench: Bench, servo: int, sign: int) -> tuple[str, float]:
    """Turn one servo one way, watched from the body's roll (or by the operator): the
    verdict (``ok``, ``reversed``, ``unseen``; or ``ok``/``wrong``) and the roll, rad."""
    command = (sign, 0) if servo == 0 else (0, sign)
    name, way = SERVOS[servo], "forward" if sign > 0 else "in reverse"
    if bench.source is None:
        bench.say(f"The {name} leg turns {way} for {TURN_SECONDS:.0f} s now.")
        bench.run(TURN_SECONDS, command)
        bench.stop()
        assert bench.ask is not None
        seen = bench.ask(f"Did the {name} leg turn {way} (the way that rolls the robot "
                         f"{'forward' if sign > 0 else 'backward'})?")
        return "ok" if seen else "wrong", 0.0
    roll = 0.0
    for _ in range(TURN_ATTEMPTS):  # the leg's phase differs each time: one that lifts the body shows
        poses = bench.run(TURN_SECONDS, command)
        poses += bench.stop()
        roll = body_roll(poses + bench.run(SETTLE_SECONDS))
        if abs(roll) > ROLL_SEEN:
            break
    verdict = "ok" if roll * sign > ROLL_SEEN else "reversed" if roll * sign < -ROLL_SEEN else "unseen"
    return verdict, roll


def _turn_each_servo(bench: Bench) -> tuple[dict[str, list[str]], dict[str, list[float]]]:
    """Each servo alone, forward then reverse: per servo the two verdicts and body rolls.

    One leg turning alone can, now and then, tip the body back over the other leg (in
    simulation 2 of 1 800 turns of the ξ = 3 robot rolled it backward). A servo wired or
    trimmed the wrong way round is reversed both ways, so when the two ways disagree (one
    ``ok``, one ``reversed``) both are watched once more, and the second pair is the verdict."""
    verdicts: dict[str, list[str]] = {}
    rolls: dict[str, list[float]] = {}
    for i, servo in enumerate(SERVOS):
        for _ in range(2):
            forward, reverse = _turn(bench, i, +1), _turn(bench, i, -1)
            verdicts[servo], rolls[servo] = [forward[0], reverse[0]], [forward[1], reverse[1]]
            if bench.source is None or sorted(verdicts[servo]) != ["ok", "reversed"]:
                break
    return verdicts, rolls


def _servo_check(bench: Bench, trims: dict[str, dict[str, int]] | None) -> Check:
    """Each servo alone, forward then reverse, watched from the body's roll (or by the operator)."""
    if bench.source is None and bench.ask is None:
        return Check("servos", None, "not checked: needs --mocap or an operator at a terminal")
    measured = bench.source is not None
    verdicts, rolls = _turn_each_servo(bench)
    if measured and all(verdicts[s] == ["reversed", "reversed"] for s in SERVOS):
        return Check("servos", False, "both servos look reversed: more likely the rigid body's x axis points to the "
                                      "left leg (the roll about x changes sign)",
                     f"define the rigid body with x toward the right leg ({FRAME_DOC}); if it is, flip both "
                     "directions with tumblebot trim")
    problems, fixes = [], []
    for servo in SERVOS:
        v = verdicts[servo]
        if v == ["ok", "ok"]:
            continue
        if v == ["reversed", "reversed"]:
            problems.append(f"{servo} servo reversed: told forward, its leg turned backward")
            flip = -(trims or {}).get(servo, {}).get("direction", +1 if servo == "right" else -1)
            fixes.append(f"tumblebot trim --servo {servo} --direction {flip:+d}")
        elif "unseen" in v and "reversed" not in v:
            problems.append(f"{servo} servo: the body did not roll when it was told to turn "
                            f"({'/'.join(f'{r:+.2f}' for r in rolls[servo])} rad)")
            fixes.append(f"is the {servo} servo powered and its leg fixed to the horn? (a body one leg "
                         "cannot lift shows no roll: then check without --mocap, watching the leg)")
        else:
            problems.append(f"{servo} servo did not turn both ways as told ({', '.join(v)})")
            fixes.append(f"check the {servo} servo's wiring and trim")
    if problems:
        return Check("servos", False, "; ".join(problems), "; ".join(fixes))
    if not measured:
        return Check("servos", True, "the operator saw each leg turn both ways as told")
    shown = ", ".join(f"{s} {rolls[s][0]:+.2f}/{rolls[s][1]:+.2f} rad" for s in SERVOS)
    return Check("servos", True, f"each turns both ways as told (body roll forward/reverse: {shown})")


def _watchdog_check(bench: Bench) -> Check:
    """Drive, then fall silent: the agent must stop the legs (its host timeout)."""
    before = bench.telemetry(ANSWER_WAIT)
    if before is None:
        return Check("watchdog", None, "not checked: the agent stopped answering")
    timeouts = int(before.get("host_timeouts", 0))
    bench.run(1.0, (1, 1))
    bench.agent.poll()
    bench.run(SILENCE_SECONDS, None)  # not a datagram: the host has gone silent
    after = bench.telemetry(ANSWER_WAIT, lambda b: int(b.get("host_timeouts", 0)) > timeouts
                            and _firmware_speeds(b) == (0, 0))
    # Watched once the Arduino says stopped, still silent: a body stopped mid-tumble may tip
    # onto a face, and poses may arrive late, so the second judged is the last of two.
    poses = bench.run(SETTLE_SECONDS + 1.0, None) if after is not None and bench.source is not None else []
    bench.stop()
    if after is None:
        last = bench.agent.last_telemetry
        if int(last.get("host_timeouts", 0)) <= timeouts:
            return Check("watchdog", False, f"the host was silent {SILENCE_SECONDS:.1f} s and the agent did not stop "
                                            "the legs", "update the Pi agent (its host timeout is 1 s)")
        return Check("watchdog", False, f"the agent stopped, but the Arduino still runs the servos at "
                                        f"{_firmware_speeds(last)}", "flash the firmware of this repository")
    detail = "the host fell silent while driving; the agent stopped the legs, the Arduino reports them stopped"
    if poses:
        tail = [p for p in poses if p.t >= poses[-1].t - 1.0]
        moved, turned = motion(tail)
        if moved > STOPPED_MOVE or turned > STOPPED_TURN:  # a driving robot covers more, a settling one less
            return Check("watchdog", False, f"the agent and the Arduino say stopped, but the robot moved "
                                            f"{1e3 * moved:.0f} mm / {math.degrees(turned):.0f}° in a second "
                                            "watched after they did", "are the servos on D9 and D10 of this Arduino?")
        detail += f" (a second watched after: {1e3 * moved:.0f} mm, {math.degrees(turned):.0f}°)"
    return Check("watchdog", True, detail)


def _firmware_speeds(body: dict[str, Any]) -> tuple[int, int] | None:
    status = body.get("firmware_status")
    if not isinstance(status, dict):
        return None
    return int(status.get("right", 0)), int(status.get("left", 0))


def check(bench: Bench) -> list[Check]:
    """Every check of :data:`CHECKS`, in order; later ones are skipped when the link is down."""
    checks, body = _link_checks(bench)
    if body is None:
        done = {c.name for c in checks}
        return checks + [Check(name, None, "not checked: no link to the Arduino") for name in CHECKS
                         if name not in done]
    bench.stop()
    if bench.source is not None:
        checks.append(_mocap_check(bench))
    else:
        checks.append(Check("mocap", None, "not checked: no --mocap"))
    checks.append(_still_check(bench))
    checks.append(_servo_check(bench, trims_of(body)))
    checks.append(_watchdog_check(bench))
    return checks


def operator(prompt: str) -> bool:
    """Ask a yes/no question at the terminal."""
    while True:
        answer = input(f"{prompt} [y/n] ").strip().lower()
        if answer in ("y", "yes", "n", "no"):
            return answer.startswith("y")


def operator_if_terminal() -> Callable[[str], bool] | None:
    return operator if sys.stdin is not None and sys.stdin.isatty() else None
