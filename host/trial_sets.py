"""Field trials (thesis §3.3): a trial set, run trial by trial, resumable; and its analysis.

A trial set is a folder::

    plan.json          what the set is: setpoint, start points, order, policy, design
    index.json         finished trials and aborted attempts (replaced atomically)
    trial-0007.mcap    one crash-safe log per trial (tumblebot.host.triallog)

``run_trial_set`` places the robot for the next unfinished trial (an operator guided on
the terminal, or the digital twin told where to put it), runs the controller, and records
the trial. Stopping at any moment loses nothing finished; running the same command again
continues with the next unfinished trial.
"""

from __future__ import annotations

import json
import math
import socket
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.errors import TumblebotError
from tumblebot.host.mocap import PoseSource
from tumblebot.host.trial_runner import COMPLETE, ControllerConfig, TrialResult, TrialRunner
from tumblebot.host.triallog import BackgroundLog, TrialLogWriter, read_trial, write_json_atomic
from tumblebot.sim.evaluation.stats import mean_ci95
from tumblebot.sim.world.design import Design

PLAN_VERSION = 1


class TrialError(TumblebotError):
    """A trial set that cannot be run or analysed as asked."""


def _quiet(message: str) -> None:
    """The default for ``out`` callbacks: library code prints nothing; the CLI passes its own."""


@dataclass(frozen=True)
class TrialPlan:
    setpoint: tuple[float, float]
    heading: float
    radius: float
    points: int
    per_point: int
    task: str
    policy: str
    policy_sha256: str
    design: tuple[float, float, float, float]
    seed: int
    controller: dict[str, Any]

    @property
    def trials(self) -> int:
        return self.points * self.per_point

    def start_point(self, k: int) -> tuple[float, float]:
        angle = 2 * math.pi * k / self.points
        return (self.setpoint[0] + self.radius * math.cos(angle), self.setpoint[1] + self.radius * math.sin(angle))

    def point_of(self, trial: int) -> int:
        return trial % self.points  # round robin: an interrupted set stays balanced

    def start_yaw(self, trial: int) -> float:
        """The heading the robot is placed with (random, reproducible): the twin uses it,
        an operator places the robot facing anywhere."""
        ss = np.random.SeedSequence([self.seed, trial])
        return float(np.random.default_rng(ss).uniform(-math.pi, math.pi))

    def to_json(self) -> dict[str, Any]:
        return {"version": PLAN_VERSION, **asdict(self),
                "start_points": [self.start_point(k) for k in range(self.points)]}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TrialPlan:
        if data.get("version") != PLAN_VERSION:
            raise TrialError(f"plan version {data.get('version')!r} is not {PLAN_VERSION}")
        fields = {k: data[k] for k in cls.__dataclass_fields__}
        fields["setpoint"] = tuple(fields["setpoint"])
        fields["design"] = tuple(fields["design"])
        return cls(**fields)


def load_index(folder: Path) -> dict[str, Any]:
    path = folder / "index.json"
    if not path.exists():
        return {"trials": [], "aborted": []}
    try:
        data: dict[str, Any] = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise TrialError(f"{path} is not valid JSON ({exc}); it is written atomically, so it was edited by hand") \
            from None
    return data


def open_trial_set(folder: Path, plan: TrialPlan) -> TrialPlan:
    """Create the set, or check that an existing one is the same set (then resume it)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "plan.json"
    if path.exists():
        existing = TrialPlan.from_json(json.loads(path.read_text()))
        if existing != plan:
            mine, theirs = asdict(existing), asdict(plan)
            diff = [f"{k}: set has {mine[k]!r}, command asks for {theirs[k]!r}" for k in mine if mine[k] != theirs[k]]
            raise TrialError(f"{folder} holds a different trial set; nothing was changed. " + "; ".join(diff))
        return existing
    write_json_atomic(path, plan.to_json())
    write_json_atomic(folder / "index.json", {"trials": [], "aborted": []})
    return plan


# ----------------------------------------------------------------------------- placement
class Placer:
    def place(self, trial: int, point: tuple[float, float], yaw: float) -> None:
        raise NotImplementedError


class OperatorPlacer(Placer):
    """Guides a person: where to put the robot, and its live distance to that spot."""

    def __init__(self, source: PoseSource, tolerance: float = 0.10, settle: float = 1.0,
                 out: Callable[[str], None] = _quiet, status: Callable[[str], None] = _quiet) -> None:
        """``out`` gets whole lines (instructions); ``status`` a live line that replaces
        the previous one (the distance to the start point, twice a second), then ``""``."""
        self.source, self.tolerance, self.settle, self.out, self.status = source, tolerance, settle, out, status

    def place(self, trial: int, point: tuple[float, float], yaw: float) -> None:
        self.out(f"place the robot at ({point[0]:+.2f}, {point[1]:+.2f}) m, facing any way; the trial starts when "
                 f"it has been within {self.tolerance:.2f} m of that spot for {self.settle:.0f} s")
        inside_since: float | None = None
        last_print = 0.0
        while True:
            for pose in self.source.poll(0.1):
                d = math.hypot(pose.position[0] - point[0], pose.position[1] - point[1])
                now = time.monotonic()
                if now - last_print > 0.5:
                    self.status(f"  distance to the start point: {d:5.2f} m ")
                    last_print = now
                inside_since = (inside_since or now) if d <= self.tolerance else None
                if inside_since is not None and now - inside_since >= self.settle:
                    self.status("")
                    return


class TwinPlacer(Placer):
    """Tells the digital twin's world process to put the robot at the start point."""

    def __init__(self, address: tuple[str, int], timeout: float = 10.0) -> None:
        self.address, self.timeout = address, timeout

    def place(self, trial: int, point: tuple[float, float], yaw: float) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.settimeout(self.timeout)
            s.sendto(json.dumps({"cmd": "place", "trial": trial, "x": point[0], "y": point[1], "yaw": yaw}).encode(),
                     self.address)
            try:
                reply = json.loads(s.recv(4096))
            except (TimeoutError, OSError):
                raise TrialError(f"the twin at {self.address[0]}:{self.address[1]} did not answer") from None
        if reply.get("ok") is not True:
            raise TrialError(f"the twin refused to place the robot: {reply.get('error')}")


# ----------------------------------------------------------------------------- running
def run_trial_set(folder: Path, plan: TrialPlan, controller: TrialRunner, placer: Placer,
                  out: Callable[[str], None] = _quiet, agent_wait: float = 300.0,
                  on_logged: Callable[[int], None] | None = None,
                  mirror: Callable[[str, bytes, int], None] | None = None) -> dict[str, Any]:
    """Run every unfinished trial of the set. Returns the index. ``mirror`` sees every
    logged message (:class:`~tumblebot.host.triallog.TrialLogWriter`), for a live view."""
    index = load_index(folder)
    done = {t["trial"] for t in index["trials"]}
    if any(trial not in done for trial in range(plan.trials)):
        check_link(controller, min(agent_wait, LINK_CHECK_WAIT))  # no trial starts on a link that cannot move the robot
    for trial in range(plan.trials):
        if trial in done:
            continue
        while True:  # attempts of this trial, until one completes
            k = plan.point_of(trial)
            point = plan.start_point(k)
            out(f"trial {trial + 1}/{plan.trials} (start point {k + 1} of {plan.points})")
            placer.place(trial, point, plan.start_yaw(trial))
            path = folder / f"trial-{trial:04d}.mcap"
            if path.exists():  # the host died during this trial (kill -9, power): keep its log, redo the trial
                _set_aside(folder, index, trial, path, "host_crashed", "the host stopped during the trial")
            log = TrialLogWriter(path, {"trial": str(trial), "point": str(k), "start": json.dumps(point),
                                        "setpoint": json.dumps(plan.setpoint), "design": json.dumps(plan.design),
                                        "radius": str(plan.radius),
                                        "policy_sha256": plan.policy_sha256}, on_written=on_logged,
                                  mirror=mirror)
            result: TrialResult | None = None
            background = BackgroundLog(log)  # the controller never waits for the disk
            starts = getattr(controller.source, "trial_starts", None)
            if starts is not None:  # a recorded trial (replay://) plays from here
                starts()
            try:
                result = controller.run_trial(background, on_status=lambda n, pose, d: out(
                    f"  step {n:2d}/{controller.config.steps}: {d:.2f} m to the setpoint"))
            finally:
                try:
                    background.close()
                finally:
                    log.finish()
                if result is None or result.status != COMPLETE:
                    _set_aside(folder, index, trial, path, result.status if result else "interrupted",
                               result.reason if result else "stopped (Ctrl-C or an error)")
            assert result is not None
            if result.status == COMPLETE:
                index["trials"].append({"trial": trial, "point": k, "start": list(point), "file": path.name,
                                        "final_position": list(result.final_position or ()),
                                        "final_error": result.final_error,
                                        "latency_ms_p50": float(np.median(result.latencies_ms))
                                        if result.latencies_ms else None,
                                        "finished": time.strftime("%Y-%m-%dT%H:%M:%S")})
                write_json_atomic(folder / "index.json", index)
                out(f"  done: final error {result.final_error:.3f} m")
                break
            _recover(result, controller, agent_wait, out)
    return index


def _recover(result: TrialResult, controller: TrialRunner, agent_wait: float, out: Callable[[str], None]) -> None:
    """After an aborted trial: say why, and wait for what it needs before it is redone."""
    out(f"  trial aborted ({result.status}): {result.reason}; the robot was stopped. The trial will be redone.")
    if result.status == "agent_lost":
        _wait_for_agent(controller, agent_wait, out)
    elif result.status == "taken_over":
        out("another host took control of the robot: waiting for it to give control back (it does as it ends)")
        check_link(controller, agent_wait)
        out("control is back; continuing")
    elif result.status in LINK_FAULTS:
        out("waiting for the agent's serial link to the Arduino (check the USB cable and the servo supply)")
        check_link(controller, agent_wait)
        out("the Arduino answers again; continuing")


LINK_CHECK_WAIT = 15.0  #: s a trial set waits at its start for the agent to report a live serial link
LINK_FAULTS = ("serial_lost", "firmware_reboot", "no_ack", "taken_over")  #: aborts that say the robot could not act


def check_link(controller: TrialRunner, timeout: float) -> dict[str, Any]:
    """Wait until the agent answers with a live serial link to the Arduino; returns that
    telemetry. Raises :class:`TrialError` (one line, saying which) when the agent does not
    answer or its serial link stays down for ``timeout`` s."""
    agent = controller.agent
    body = agent.telemetry_until(timeout, lambda body: TrialRunner.link_fault(body, sender=agent.sender) is None)
    if body is not None:
        return body
    if not agent.last_telemetry:
        where = f"{agent.address[0]}:{agent.address[1]}"
        raise TrialError(f"the agent at {where} did not answer within {timeout:.0f} s (is it running, with this key?)")
    fault = TrialRunner.link_fault(agent.last_telemetry, sender=agent.sender)
    assert fault is not None
    raise TrialError(f"no trial started: {fault[1]} (waited {timeout:.0f} s; run the same command to resume)")


def _set_aside(folder: Path, index: dict[str, Any], trial: int, path: Path, status: str, reason: str) -> None:
    """Keep an unfinished trial's log as ``trial-NNNN.aborted-K.mcap`` and record why."""
    attempt = len([a for a in index["aborted"] if a["trial"] == trial]) + 1
    aborted = path.with_name(f"trial-{trial:04d}.aborted-{attempt}.mcap")
    path.replace(aborted)
    index["aborted"].append({"trial": trial, "file": aborted.name, "status": status, "reason": reason})
    write_json_atomic(folder / "index.json", index)


def _wait_for_agent(controller: TrialRunner, timeout: float, out: Callable[[str], None]) -> None:
    agent = controller.agent
    out(f"waiting for the agent at {agent.address[0]}:{agent.address[1]} (restart it, or check the network)")
    if agent.telemetry_until(timeout, lambda body: True) is None:
        raise TrialError(f"the agent did not come back within {timeout:.0f} s; run the same command to resume")
    out("the agent answers again; continuing")


def make_plan(setpoint: tuple[float, float], heading: float, radius: float, points: int, per_point: int, task: str,
              policy: Path | str, design: Design, seed: int, config: ControllerConfig) -> TrialPlan:
    """``policy`` is an ONNX file, a hand-written navigation controller (``"goto"``,
    ``"plan"``) or a gait's name (``"excite"``, the identification run); the last two have
    no file."""
    if not (math.isfinite(radius) and radius > 0):
        raise TrialError(f"--radius {radius} must be a positive number of metres")
    if points < 1 or per_point < 1:
        raise TrialError("--points and --per-point must be at least 1")
    if not all(math.isfinite(v) for v in (*setpoint, heading)):
        raise TrialError("the setpoint and heading must be finite numbers")
    from tumblebot.sim.control.gaits import GAITS
    from tumblebot.sim.control.goto import NAVIGATORS
    from tumblebot.sim.control.policy import sha256_of

    digest = "" if str(policy) in NAVIGATORS or str(policy) in GAITS else sha256_of(Path(policy))
    return TrialPlan(setpoint, heading, radius, points, per_point, task, str(policy), digest,
                     design.as_tuple(), seed, asdict(config))


# ----------------------------------------------------------------------------- analysis
@dataclass
class SetSummary:
    folder: Path
    plan: TrialPlan
    errors: np.ndarray
    points: np.ndarray  #: start-point index of each error
    e: float


def summarize(folder: Path) -> SetSummary:
    from tumblebot.sim.world.power import energy_per_metre

    plan_path = folder / "plan.json"
    if not plan_path.exists():
        raise TrialError(f"{folder} is not a trial set (no plan.json)")
    plan = TrialPlan.from_json(json.loads(plan_path.read_text()))
    index = load_index(folder)
    trials = index["trials"]
    if not trials:
        raise TrialError(f"{folder} has no finished trial yet")
    errors = np.array([t["final_error"] for t in trials], dtype=float)
    points = np.array([t["point"] for t in trials], dtype=int)
    return SetSummary(folder, plan, errors, points, energy_per_metre(Design(*plan.design)))


def analyze(folder: Path, baseline: Path | None = None, baseline_stats: tuple[float, float, int] | None = None,
            plot: Path | None = None) -> dict[str, Any]:
    """Setpoint error per start point and overall, and a Welch t-test against a baseline."""
    from scipy import stats

    s = summarize(folder)
    out: dict[str, Any] = {"folder": str(folder), "design": s.plan.design, "e": s.e if math.isfinite(s.e) else None,
                           "n": len(s.errors), "mean_error": float(s.errors.mean()),
                           "sd_error": float(s.errors.std(ddof=1)) if len(s.errors) > 1 else 0.0,
                           "ci95": _ci95(s.errors), "per_point": []}
    for k in range(s.plan.points):
        e = s.errors[s.points == k]
        if len(e):
            out["per_point"].append({"point": k, "start": s.plan.start_point(k), "n": len(e),
                                     "mean_error": float(e.mean()), "ci95": _ci95(e)})
    if baseline is not None and baseline_stats is not None:
        raise TrialError("give --baseline DIR or the --baseline-mean/--baseline-sd/--baseline-n numbers, not both")
    if baseline is not None:
        b = summarize(baseline)
        p = None  # a t-test needs two trials on each side
        if len(s.errors) > 1 and len(b.errors) > 1:
            p = float(stats.ttest_ind(s.errors, b.errors, equal_var=False).pvalue)
        out["baseline"] = {"folder": str(baseline), "design": b.plan.design, "e": b.e if math.isfinite(b.e) else None,
                           "n": len(b.errors), "mean_error": float(b.errors.mean()),
                           "sd_error": float(b.errors.std(ddof=1)) if len(b.errors) > 1 else 0.0, "p": p}
    elif baseline_stats is not None:
        mean, sd, n = baseline_stats
        if not (math.isfinite(mean) and math.isfinite(sd) and sd >= 0 and n >= 2):
            raise TrialError("--baseline-mean and --baseline-sd must be finite (sd >= 0) and --baseline-n >= 2")
        p = None  # a t-test needs two trials on each side
        if len(s.errors) > 1:
            p = float(stats.ttest_ind_from_stats(s.errors.mean(), s.errors.std(ddof=1), len(s.errors), mean, sd, n,
                                                 equal_var=False).pvalue)
        out["baseline"] = {"mean_error": mean, "sd_error": sd, "n": n, "p": p}
    if plot is not None:
        _plot(s, plot)
        out["plot"] = str(plot)
    return out


def _ci95(errors: np.ndarray) -> tuple[float, float] | None:
    """The mean's 95 % CI, or None from a single trial (an interval needs two)."""
    return mean_ci95(errors) if len(errors) > 1 else None


def _plot(s: SetSummary, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    fig, ax = plt.subplots(figsize=(6, 6))
    index = load_index(s.folder)
    for entry in index["trials"]:
        log = read_trial(s.folder / entry["file"])
        xy = np.array([m.data["p"][:2] for m in log.topic("/pose")])
        if len(xy):
            ax.plot(xy[:, 0], xy[:, 1], lw=0.8, alpha=0.7, color=f"C{entry['point'] % 10}")
            ax.plot(xy[-1, 0], xy[-1, 1], "o", ms=3, color=f"C{entry['point'] % 10}")
    sx, sy = s.plan.setpoint
    ax.add_patch(Circle((sx, sy), s.plan.radius, fill=False, ls=":", color="grey"))
    for k in range(s.plan.points):
        px, py = s.plan.start_point(k)
        ax.plot(px, py, "s", color=f"C{k % 10}", ms=8)
    ax.plot(sx, sy, "r*", ms=16, label="setpoint")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, lab)")
    ax.set_ylabel("y (m, lab)")
    ax.set_title(f"{len(s.errors)} trials: mean setpoint error {s.errors.mean():.3f} m", fontsize=10)
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
