"""Calibration: the physics profile under which simulated motion matches a robot's logged motion.

A logged trial gives the simulator what it needs to run the same trial again: the robot's
design, where it stood and which way it faced when the first command left, and every leg
command with the moment it left (a :class:`Trace`). :func:`replay` runs a trace under a
candidate profile, open loop, and records the body's planar pose (a :class:`Track`), the
same kind of record the motion capture made. Both are cut into the trace's steps (one
command each) and summarised by :func:`statistics`: per kind of command (drive, spin,
one leg, stop, and a drive from rest, ``start``) the mean distance and turn of a step, how
quickly a drive step gets under way, how much drive steps differ in distance and spin
steps in turn (:data:`SPREADS`).

:func:`calibrate` fits the profile by simulation-based inference with a quadratic
emulator (a response surface), in two rounds:

1. Simulate the whole set of traces at points of a scrambled Sobol design over the prior
   box of every fitted parameter (free speed and stall torque on a log scale), one
   independent seed per point; fit each statistic by a quadratic in the parameters
   (least squares), and the log of its scatter about that quadratic by an affine function;
   weigh a dense quasi-random sample of the box by the Gaussian synthetic likelihood of
   the logged statistics, with the variance emulated at each point (how much the same
   trials differ from run to run depends on the world: one place's scatter of a drive's
   mean turn was a quarter of another's, nearby) plus the error of the emulated mean.
2. Zoom the box to where that posterior lies and do it again there.

The posterior's 5 %, 50 % and 95 % quantiles give each parameter its value and 90 %
interval. Identifiability is measured, not assumed: the emulator of round 1 says how far
moving a parameter across its prior box moves each statistic, in units of the statistic's
run-to-run noise (its *effect*), and a parameter counts as identified only when that
effect is at least :data:`MIN_EFFECT` and its interval lies within ±25 % of its value.
Any other parameter is reported as not identifiable and keeps the prior's value, unless
the logs rule that value out (it lies outside the parameter's 90 % posterior interval):
then the profile takes the posterior's median, so that it reproduces the logged motion,
and the report says that the value is not a confident one. The values are checked
together too: every value that shows in the logs is searched together with the others
inside its 90 % interval (Optuna's TPE, every candidate simulated; the emulator is too
coarse to rank points that close), and when the best values found lower the misfit of the
logged statistics by more than :data:`MIN_IMPROVEMENT` on 8 fresh replicates (the
misfit's yardstick is the scatter of 16 replicate simulations of the profile), the profile
takes them. The posterior's medians, one parameter at a time, need not lie where the parameters
fit the logs together (in one measured world the medians' drives went 5.6 noise SDs too
far, and the truth's 1.3; in another the medians misfit the logs by 2.8 noise SDs² on
average and the values searched together by 1.8, with the free speed at 4.48 rad/s in place
of 4.23 for a true 4.5), so an identified value moves too, but only within the part of
its interval from which that interval lies within ±25 % (:func:`_search_range`): it stays
identified, with the interval the search leaves as it was. Any other value found carries
the same caveat as before.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.errors import SimError
from tumblebot.sim.evaluation.pool import WorkerPool
from tumblebot.sim.world.physics import MAX_LATENCY, PhysicsProfile

RECORD_HZ = 60  #: how often a replay records the body's pose (the mocap runs at about 100 Hz)
MIN_STEPS = 6  #: logged steps a kind of command needs before its statistics count
MIN_EFFECT = 3.0  #: a parameter whose range moves no statistic this many noise SDs is not identifiable
MAX_REL_HALF_WIDTH = 0.25  #: an identified parameter's 90 % interval lies within ±25 % of its value
STILL = 0.005  #: m: a step that moves less than this never "gets under way"
#: the values searched together in their intervals replace the profile's when they lower its
#: misfit of the logged statistics (mean squared, in noise SDs) by more than this
MIN_IMPROVEMENT = 1.0

#: both legs one way; opposite ways; one leg; none; and a drive from rest (the trial's first
#: step, or after a stop), which a stopped servo's hold and the stall torque set apart
CLASSES = ("drive", "spin", "pivot", "stop", "start")
FEATURES_VERSION = 2  #: bumped when step features change: a cache of older ones is not reused


#: a full quadratic in the six fitted parameters has 1 + 6 + 21 = 28 coefficients: a round
#: needs about twice as many simulated points to fit it and to measure its own error
MIN_DESIGN_POINTS = 64
#: the rounds after the first: each zooms to the previous posterior's (tail, 1 - tail)
#: quantiles, padded by that share of their width. One such round: a third, tighter one
#: ((0.01, 0.1)) fits the logged statistics better and the truth worse (measured with the
#: first likelihood: docs/research/calibration-runs.md, the first run)
ZOOMS: tuple[tuple[float, float], ...] = ((0.0005, 0.25),)


class CalibrationError(SimError):
    """Logs or settings a calibration cannot use (one line)."""


# ----------------------------------------------------------------------------- data
@dataclass(frozen=True)
class Trace:
    """What a logged trial gives the simulator: its design, the pose at the first command
    (``x``, ``y`` in m and the heading of the legs' axis in rad), and every command
    ``(t, right, left)`` with ``t`` in s after the first one; the trial ends ``duration``
    s after the first command."""

    name: str
    design: tuple[float, float, float, float]
    start: tuple[float, float, float]
    commands: tuple[tuple[float, int, int], ...]
    duration: float

    def __post_init__(self) -> None:
        if not self.commands:
            raise CalibrationError(f"{self.name}: no leg commands")
        times = [c[0] for c in self.commands]
        if times[0] < 0 or any(b < a for a, b in itertools.pairwise(times)) \
                or not self.duration > times[-1]:
            raise CalibrationError(f"{self.name}: command times must start at 0, increase and end before the trial")
        if any(c[1] not in (-1, 0, 1) or c[2] not in (-1, 0, 1) for c in self.commands):
            raise CalibrationError(f"{self.name}: leg commands must be -1, 0 or 1")

    def digest(self) -> str:
        return hashlib.sha256(json.dumps([self.design, self.start, self.commands, self.duration]).encode()
                              ).hexdigest()[:16]


@dataclass(frozen=True)
class Track:
    """The body's planar pose over a trial: times (s after the first command), x, y (m)
    and the heading of the legs' axis (rad)."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray


def axis_heading(quaternion: Sequence[float]) -> float:
    """The lab-frame heading of the body's x axis (the legs' shared axis), rad: what a
    tumble about that axis leaves unchanged."""
    x, y, z, w = quaternion
    return math.atan2(2.0 * (x * y + w * z), 1.0 - 2.0 * (y * y + z * z))


def command_class(right: int, left: int) -> str:
    if right == 0 and left == 0:
        return "stop"
    if right == left:
        return "drive"
    if right == -left:
        return "spin"
    return "pivot"


# ----------------------------------------------------------------------------- replay
def replay(env: Any, trace: Trace, seed: int) -> Track:
    """Run ``trace`` open loop in ``env`` (a :class:`~tumblebot.sim.world.env.TumblerEnv` built
    for the candidate profile): reset at the trace's start (its seed draws the legs'
    angles, masses, friction and motor noise), then each command from its time plus a
    latency drawn from the profile's range."""
    from tumblebot.sim.world.design import Design

    env.reset(seed=seed, options={"design": Design(*trace.design), "start_xy": trace.start[:2],
                                  "start_yaw": trace.start[2]})
    hz = env.physics_hz
    lo, hi = env.randomization.latency
    rng = np.random.default_rng([seed, 0x1A7E])
    events = sorted((round((t + rng.uniform(lo, hi)) * hz), k, r, lft) for k, (t, r, lft) in enumerate(trace.commands))
    end = round(trace.duration * hz)
    every = max(1, hz // RECORD_HZ)
    rows: list[tuple[float, float, float, float]] = []
    i, e = 0, 0
    while True:
        while e < len(events) and events[e][0] <= i:
            env.set_leg_commands(float(events[e][2]), float(events[e][3]))
            e += 1
        if i % every == 0 or i == end:
            position, quaternion = env.base_pose()
            rows.append((i / hz, position[0], position[1], axis_heading(quaternion)))
        if i >= end:
            break
        next_record = (i // every + 1) * every
        nxt = min(next_record, end, events[e][0] if e < len(events) else end)
        env.advance(max(1, nxt - i))
        i = max(i + 1, nxt)
    a = np.array(rows)
    return Track(a[:, 0], a[:, 1], a[:, 2], a[:, 3])


def step_features(trace: Trace, track: Track) -> np.ndarray:
    """One row per step: class index (into :data:`CLASSES`: a drive is a ``start`` when it is
    the first step or follows a stop), distance (m), turn (rad, its size) and the time (s)
    the step took to cover half its greatest distance from where it began (the step's
    length if it never moved :data:`STILL`)."""
    bounds = [c[0] for c in trace.commands] + [trace.duration]
    rows = []
    for k, (_, right, left) in enumerate(trace.commands):
        i0 = max(0, int(np.searchsorted(track.t, bounds[k], side="right")) - 1)
        i1 = max(i0, int(np.searchsorted(track.t, bounds[k + 1], side="right")) - 1)
        dx, dy = track.x[i1] - track.x[i0], track.y[i1] - track.y[i0]
        turn = abs(math.remainder(float(track.heading[i1] - track.heading[i0]), 2 * math.pi))
        away = np.hypot(track.x[i0:i1 + 1] - track.x[i0], track.y[i0:i1 + 1] - track.y[i0])
        length = bounds[k + 1] - bounds[k]
        if away.max() < STILL:
            t50 = length
        else:
            t50 = float(track.t[i0 + int(np.argmax(away >= 0.5 * away.max()))] - track.t[i0])
        kind = command_class(right, left)
        if kind == "drive" and (k == 0 or command_class(*trace.commands[k - 1][1:]) == "stop"):
            kind = "start"
        rows.append((CLASSES.index(kind), math.hypot(dx, dy), turn, min(t50, length)))
    return np.array(rows, dtype=float)


#: the spreads (standard deviations from step to step) that the summary holds besides the
#: means: the drives' distance, and the spins' turn, which the motor noise sets (a spin's
#: rate is each leg's own drawn speed) more than the free speed and the floor do. With the
#: drives' spread alone, one benchmark world's motor noise was left open (0.59..1.48 rad/s
#: for a true 0.8) and fitted at 1.36, and its held-out trials were told apart; more
#: spreads still (the drives' turn, the distance of drives from rest) moved another
#: world's motor noise away from its truth (docs/research/calibration-runs.md, "More
#: spreads in the summary")
SPREADS: tuple[str, ...] = ("drive distance", "spin turn")


def check_spreads(spreads: Sequence[str]) -> None:
    """Refuses a spread :func:`statistics` cannot take (one error naming them)."""
    unknown = [s for s in spreads if s.count(" ") != 1 or s.partition(" ")[0] not in CLASSES
               or s.partition(" ")[2] not in ("distance", "turn")]
    if unknown:
        raise CalibrationError(f"no such spread: {', '.join(map(repr, unknown))} (KIND distance or KIND turn, "
                               f"KIND one of {', '.join(CLASSES)})")


def statistics(features: Sequence[np.ndarray], spreads: Sequence[str] = SPREADS) -> dict[str, float]:
    """The summary the fit matches: per kind of command with :data:`MIN_STEPS` steps or
    more, the mean distance and turn of a step; the spreads named in ``spreads`` (``"KIND
    distance"`` or ``"KIND turn"``, by default the drives' distance and the spins' turn);
    for drives how soon they get under way (mean time to half distance); for drives from
    rest and one-leg steps that time too."""
    check_spreads(spreads)
    f = np.vstack(features)
    out: dict[str, float] = {}
    for c, name in enumerate(CLASSES):
        rows = f[f[:, 0] == c]
        if len(rows) < MIN_STEPS:
            continue
        out[f"{name} distance"] = float(rows[:, 1].mean())
        out[f"{name} turn"] = float(rows[:, 2].mean())
        for column, quantity in ((1, "distance"), (2, "turn")):
            if f"{name} {quantity}" in spreads:
                out[f"{name} {quantity} sd"] = float(rows[:, column].std())
        if name in ("drive", "pivot", "start"):
            out[f"{name} time to half"] = float(rows[:, 3].mean())
    return out


# ----------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class Parameter:
    """A fitted parameter: its name (a profile key), unit, prior box and scale."""

    name: str
    unit: str
    log: bool

    def value(self, profile: PhysicsProfile) -> float:
        if self.name == "latency":
            return 0.5 * (profile.latency[0] + profile.latency[1])
        return float(getattr(profile, self.name))

    def box(self, prior: PhysicsProfile) -> tuple[float, float]:
        v = self.value(prior)
        if self.name == "free_speed":
            return v / 2.0, v * 2.0
        if self.name == "stall_torque":
            from tumblebot.sim.world import constants as C

            return v / 3.0, min(v * 3.0, C.MAX_STALL_TORQUE)
        if self.name == "friction":
            return min(0.3, v / 2.0), max(1.5, v * 1.5)
        if self.name == "hold_torque":
            return 0.0, max(1.0, 3.0 * v)
        if self.name == "latency":
            return 0.0, max(0.2, 2.0 * v)
        if self.name == "motor_speed_sigma":
            return 0.0, max(2.0, 2.0 * v)
        raise CalibrationError(f"no prior box for {self.name}")

    def apply(self, profile: PhysicsProfile, value: float) -> PhysicsProfile:
        if self.name == "latency":  # the mean moves; the spread stays the prior's where it can
            lo0, hi0 = profile.latency
            lo = max(0.0, value - 0.5 * (hi0 - lo0))
            return replace(profile, latency=(lo, min(MAX_LATENCY, 2.0 * value - lo)))
        return replace(profile, **{self.name: float(value)})  # type: ignore[arg-type]

    def to_unit(self, value: np.ndarray, box: tuple[float, float]) -> np.ndarray:
        lo, hi = box
        if self.log:
            return np.asarray((np.log(value) - math.log(lo)) / (math.log(hi) - math.log(lo)), dtype=float)
        return np.asarray((value - lo) / (hi - lo), dtype=float)

    def from_unit(self, u: np.ndarray, box: tuple[float, float]) -> np.ndarray:
        lo, hi = box
        if self.log:
            return np.asarray(np.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))), dtype=float)
        return np.asarray(lo + u * (hi - lo), dtype=float)


PARAMETERS: tuple[Parameter, ...] = (
    Parameter("free_speed", "rad/s", True),
    Parameter("stall_torque", "N·m", True),
    Parameter("friction", "", False),
    Parameter("hold_torque", "N·m", False),
    Parameter("latency", "s (mean)", False),
    Parameter("motor_speed_sigma", "rad/s", False),
)
NOT_FITTED = ("motor_model", "friction_rel_sigma")  #: kept from the prior: the logs hardly show them


def profile_at(prior: PhysicsProfile, values: dict[str, float], name: str | None = None) -> PhysicsProfile:
    out = prior
    for p in PARAMETERS:
        if p.name in values:
            out = p.apply(out, values[p.name])
    return replace(out, name=name or out.name)


# ----------------------------------------------------------------------------- simulating
def simulate_set(traces: Sequence[Trace], profile: PhysicsProfile, seed: int) -> list[np.ndarray]:
    """Every trace replayed once under ``profile``: its step features, trace by trace."""
    env = profile.make_env("nav-flat")
    try:
        return [step_features(trace, replay(env, trace, int(np.random.SeedSequence([seed, j]).generate_state(1)[0])))
                for j, trace in enumerate(traces)]
    finally:
        env.close()


def _traces_of(traces: tuple[Trace, ...]) -> tuple[Trace, ...]:
    """A worker's state: the trace set it replays."""
    return traces


def _run_job(traces: tuple[Trace, ...], item: tuple[int, tuple[dict[str, Any], int]]
             ) -> tuple[int, list[list[list[float]]]]:
    n, (values, seed) = item
    return n, [f.tolist() for f in simulate_set(traces, PhysicsProfile.from_json(values), seed)]


class Simulator:
    """Simulates the trace set under many profiles, in worker processes, remembering every
    result in a cache file (one JSON line each, appended as it comes), so an interrupted
    calibration resumes where it stopped."""

    def __init__(self, traces: Sequence[Trace], workers: int = 1, cache: Path | None = None,
                 on_done: Callable[[int], object] | None = None) -> None:
        self.traces = tuple(traces)
        self.key = hashlib.sha256((f"v{FEATURES_VERSION}" + "".join(t.digest() for t in self.traces)).encode()
                                  ).hexdigest()[:16]
        self.cache_path = cache
        self.on_done = on_done
        self.done: dict[str, list[np.ndarray]] = {}
        self.simulated = 0  #: sets simulated by this process (not read from the cache)
        if cache is not None and cache.is_file():
            for line in cache.read_text().splitlines():
                try:
                    item = json.loads(line)
                    self.done[item["key"]] = [np.array(f, dtype=float) for f in item["features"]]
                except (json.JSONDecodeError, KeyError, TypeError):
                    continue  # a line cut short by a kill: simulated again
        self._pool: WorkerPool[tuple[Trace, ...]] | None = None
        self.workers = workers

    def _key(self, profile: PhysicsProfile, seed: int) -> str:
        return hashlib.sha256(f"{self.key} {profile.digest()} {seed}".encode()).hexdigest()[:24]

    def run(self, jobs: Sequence[tuple[PhysicsProfile, int]]) -> list[list[np.ndarray]]:
        """Step features of each ``(profile, seed)``: from the cache, or simulated."""
        keys = [self._key(p, s) for p, s in jobs]
        todo = [(i, k) for i, k in enumerate(keys) if k not in self.done]
        for _ in range(len(jobs) - len(todo)):
            if self.on_done is not None:
                self.on_done(1)
        if todo:
            payload = [(jobs[i][0].to_json(), jobs[i][1]) for i, _ in todo]
            if self._pool is None:
                self._pool = WorkerPool(_traces_of, (self.traces,), self.workers)
            results = self._pool.imap_unordered(_run_job, list(enumerate(payload)))
            cache = self.cache_path.open("a") if self.cache_path is not None else None
            try:
                for n, features in results:
                    key = todo[n][1]
                    self.done[key] = [np.array(f, dtype=float) for f in features]
                    self.simulated += 1
                    if cache is not None:
                        cache.write(json.dumps({"key": key, "features": features}, separators=(",", ":")) + "\n")
                        cache.flush()
                    if self.on_done is not None:
                        self.on_done(1)
            finally:
                if cache is not None:
                    cache.close()
        return [self.done[k] for k in keys]

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None


# ----------------------------------------------------------------------------- the fit
@dataclass(frozen=True)
class Settings:
    """How much simulation a calibration spends (the defaults: about 5 minutes for 15
    trials on two cores)."""

    design_points: int = 128  #: Sobol points of round 1 (round 2 has half as many)
    replicates: int = 8  #: replicate simulations that measure run-to-run noise
    posterior_samples: int = 1 << 15
    search_trials: int = 48  #: candidates of the values' joint search (when it runs)
    search_replicates: int = 3  #: simulations of each, with the same seeds for every candidate
    seed: int = 0
    spreads: tuple[str, ...] = SPREADS  #: the spreads the summary holds (:func:`statistics`)

    def __post_init__(self) -> None:
        if self.design_points < MIN_DESIGN_POINTS or self.replicates < 3:
            raise CalibrationError(f"a calibration needs at least {MIN_DESIGN_POINTS} design points and 3 replicates")
        if self.search_trials < 2 or self.search_replicates < 1:
            raise CalibrationError("the values' joint search needs at least 2 trials and 1 replicate")
        check_spreads(self.spreads)

    def rounds(self) -> tuple[int, ...]:
        """How many Sobol points each round simulates."""
        later = max(MIN_DESIGN_POINTS, self.design_points // 2)
        return (self.design_points,) + (later,) * len(ZOOMS)

    def simulations(self) -> int:
        """Simulated trial sets of the rounds, the prior's replicates and twice as many of the fitted profile's."""
        return self.replicates * 3 + sum(self.rounds())

    def search_simulations(self) -> int:
        """Simulated trial sets of the values' joint check, when it runs."""
        return self.search_trials * self.search_replicates + self.replicates


def _linear(u: np.ndarray) -> np.ndarray:
    """The features of an affine function of ``u`` (rows are points in the unit box)."""
    return np.column_stack([np.ones(len(u)), u - 0.5])


def _quadratic(u: np.ndarray) -> np.ndarray:
    """The features of a full quadratic in ``u``: the affine ones, then every product."""
    z = u - 0.5
    k = z.shape[1]
    return np.column_stack([_linear(u)] + [z[:, i] * z[:, j] for i in range(k) for j in range(i, k)])


#: E[log χ²₁]: the log of a squared Gaussian residual falls short of the log variance by this, on average
_LOG_CHI2_1 = -1.2703628454614782


@dataclass
class Emulator:
    """Each statistic as a quadratic in the parameters (on the unit box), fitted by least
    squares, and the log of its variance about that quadratic as an affine function of the
    parameters: how much a simulated trial set's statistic scatters depends on where it was
    simulated (a drive's mean turn, 3.6 times as much at one fitted profile as at a place
    near it with less motor noise), and a likelihood that took one place's scatter for
    every place's would weigh some statistics far too much elsewhere."""

    coef: np.ndarray  #: (features, statistics)
    log_var: np.ndarray  #: (affine features, statistics): the log variance about the quadratic
    points: int

    @classmethod
    def fit(cls, u: np.ndarray, y: np.ndarray) -> Emulator:
        from scipy.linalg import lstsq

        x = _quadratic(u)
        coef, _, _, _ = lstsq(x, y)
        resid = y - x @ coef
        dof = max(1, len(u) - x.shape[1])
        residual_var = (resid ** 2).sum(axis=0) / dof
        # a least-squares residual is smaller than the scatter by (dof / points) on average
        squared = resid ** 2 * (len(u) / dof) + 1e-6 * residual_var + 1e-24
        log_var, _, _, _ = lstsq(_linear(u), np.log(squared) - _LOG_CHI2_1)
        return cls(np.asarray(coef), np.asarray(log_var), len(u))

    def predict(self, u: np.ndarray) -> np.ndarray:
        return np.asarray(_quadratic(u) @ self.coef)

    def variance(self, u: np.ndarray) -> np.ndarray:
        """Each statistic's variance about the quadratic at ``u``: one set's run-to-run
        scatter and the quadratic's lack of fit there, together."""
        return np.asarray(np.exp(_linear(np.atleast_2d(u)) @ self.log_var))


def _weighted_quantiles(values: np.ndarray, weights: np.ndarray, qs: Sequence[float]) -> list[float]:
    order = np.argsort(values)
    cdf = np.cumsum(weights[order])
    cdf /= cdf[-1]
    return [float(values[order][min(len(values) - 1, int(np.searchsorted(cdf, q)))]) for q in qs]


@dataclass
class Calibration:
    """A calibration's outcome: the fitted profile, each parameter's estimate, and the fit."""

    profile: PhysicsProfile
    prior: PhysicsProfile
    parameters: dict[str, dict[str, Any]]
    fit: dict[str, Any]
    features: dict[str, list[np.ndarray]] = field(default_factory=dict)  #: logged, prior, fitted (for the plot)

    def to_json(self) -> dict[str, Any]:
        return {"parameters": self.parameters, "fit": self.fit, "profile": self.profile.record(),
                "prior": self.prior.record()}


Box = list[tuple[float, float]]


class _Fit:
    """The rounds of :func:`calibrate` over one set of logged statistics."""

    def __init__(self, observed: dict[str, float], prior: PhysicsProfile, simulator: Simulator,
                 settings: Settings) -> None:
        self.names = list(observed)
        self.s_obs = np.array([observed[n] for n in self.names])
        self.prior, self.simulator, self.settings = prior, simulator, settings
        self.params = PARAMETERS
        self.box1: Box = [p.box(prior) for p in self.params]

    def stats_of(self, features: list[np.ndarray]) -> np.ndarray:
        s = statistics(features, self.settings.spreads)
        return np.array([s.get(n, np.nan) for n in self.names])

    def profile_u(self, u: np.ndarray, box: Box) -> PhysicsProfile:
        return profile_at(self.prior, {p.name: float(p.from_unit(np.array(u[j]), box[j]))
                                       for j, p in enumerate(self.params)})

    def replicate(self, profile: PhysicsProfile, base: int, times: int = 1
                  ) -> tuple[np.ndarray, list[list[np.ndarray]]]:
        """Statistics of ``times`` × ``replicates`` runs of the whole set under ``profile``
        (seeds from ``base``)."""
        runs = self.simulator.run([(profile, base + r) for r in range(times * self.settings.replicates)])
        return np.array([self.stats_of(f) for f in runs]), runs

    def design(self, n: int, box: Box, seed: int, base: int) -> tuple[np.ndarray, np.ndarray]:
        """A scrambled Sobol design of ``n`` points in ``box`` (unit coordinates) and their statistics."""
        from scipy.stats import qmc

        u = qmc.Sobol(len(self.params), scramble=True, seed=seed).random(n)
        runs = self.simulator.run([(self.profile_u(row, box), base + i) for i, row in enumerate(u)])
        y = np.array([self.stats_of(f) for f in runs])
        keep = np.all(np.isfinite(y), axis=1)
        return u[keep], y[keep]

    def posterior(self, emulator: Emulator, box: Box, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """Quasi-random points of ``box`` (parameter values) and their normalised weights under
        the Gaussian synthetic likelihood, whose variance at each point is the emulator's
        there (run-to-run scatter and lack of fit, :meth:`Emulator.variance`) plus the error
        of its estimated mean; the log of that variance enters too, so that a place of large
        scatter is not favoured for fitting everything loosely."""
        from scipy.stats import qmc

        u = qmc.Sobol(len(self.params), scramble=True, seed=seed).random(self.settings.posterior_samples)
        scatter = emulator.variance(u)
        var = scatter * (1.0 + _quadratic(u[:1]).shape[1] / emulator.points)
        loglik = -0.5 * ((((self.s_obs - emulator.predict(u)) ** 2) / var) + np.log(var)).sum(axis=1)
        w = np.exp(loglik - loglik.max())
        values = self.values(u, box)
        return values, w / w.sum()

    def effects(self, emulator: Emulator, noise_var: np.ndarray, centre: np.ndarray) -> dict[str, tuple[float, str]]:
        """What each parameter does to the statistics: the most any moves (in noise SDs) as
        the parameter crosses its prior box, the others at ``centre`` (unit coordinates)."""
        out = {}
        for j, p in enumerate(self.params):
            ends = np.repeat(centre[None, :], 2, axis=0)
            ends[:, j] = (0.0, 1.0)
            delta = np.abs(np.diff(emulator.predict(ends), axis=0)[0]) / np.sqrt(noise_var)
            out[p.name] = (float(delta.max()), self.names[int(delta.argmax())])
        return out

    def zoom(self, values: np.ndarray, w: np.ndarray, tail: float, pad: float) -> Box:
        """The part of the prior box where a posterior lies: its ``tail`` and ``1 - tail``
        quantiles, padded by ``pad`` of that width (in unit coordinates) and 0.02."""
        box = []
        for j, p in enumerate(self.params):
            lo, hi = _weighted_quantiles(values[:, j], w, [tail, 1.0 - tail])
            ulo, uhi = (float(v) for v in p.to_unit(np.array([lo, hi]), self.box1[j]))
            margin = pad * (uhi - ulo) + 0.02
            ulo, uhi = max(0.0, ulo - margin), min(1.0, uhi + margin)
            box.append((float(p.from_unit(np.array(ulo), self.box1[j])),
                        float(p.from_unit(np.array(uhi), self.box1[j]))))
        return box

    def values(self, u: np.ndarray, box: Box) -> np.ndarray:
        """Unit coordinates of ``box`` as parameter values."""
        return np.column_stack([p.from_unit(u[:, j], box[j]) for j, p in enumerate(self.params)])

    def units(self, values: np.ndarray, box: Box) -> np.ndarray:
        """Parameter values as unit coordinates of ``box``."""
        u = np.column_stack([p.to_unit(values[:, j], box[j]) for j, p in enumerate(self.params)])
        return u.reshape(-1, len(self.params))

    def inside(self, values: np.ndarray, box: Box) -> np.ndarray:
        """Which of the points ``values`` lie in ``box``."""
        return np.asarray(np.all((values >= [b[0] for b in box]) & (values <= [b[1] for b in box]), axis=1))

    def misfit(self, stats: np.ndarray, noise: np.ndarray) -> float:
        """How far replicate runs' mean statistics lie from the logged ones: mean squared, in noise SDs."""
        return float((((stats.mean(axis=0) - self.s_obs) ** 2) / noise).mean())

    def median(self, values: np.ndarray, w: np.ndarray) -> dict[str, float]:
        return {p.name: _weighted_quantiles(values[:, j], w, [0.5])[0] for j, p in enumerate(self.params)}


def _narrow(low: float, high: float, value: float) -> bool:
    """Whether the interval ``low``..``high`` lies within ±:data:`MAX_REL_HALF_WIDTH` of ``value``."""
    return value > 0 and low >= (1 - MAX_REL_HALF_WIDTH) * value and high <= (1 + MAX_REL_HALF_WIDTH) * value


def _estimate(p: Parameter, prior: PhysicsProfile, quantiles: list[float], effect: tuple[float, str],
              box: tuple[float, float]) -> dict[str, Any]:
    """One parameter's verdict: identified (value and 90 % interval), or why not, and then
    what the profile takes (the prior's value, unless the logs rule it out)."""
    q05, q50, q95 = quantiles
    size, where = effect
    identifiable = size >= MIN_EFFECT and _narrow(q05, q95, q50)
    kept = p.value(prior)
    value, lo, hi, keep = kept, box[0], box[1], True
    if identifiable:
        value, lo, hi, keep = q50, q05, q95, False
        why = f"moves {where} by {size:.1f} noise SDs across its range"
    elif size < MIN_EFFECT:
        why = (f"barely shows in these logs: across its whole prior range it moves no statistic more than "
               f"{size:.1f} noise SDs (most: {where}); the prior's value is kept")
    elif q05 <= kept <= q95:
        lo, hi = q05, q95
        why = (f"shows in these logs ({where}, {size:.1f} noise SDs) but they leave it uncertain: 90 % of the "
               f"posterior lies in {q05:.3g}..{q95:.3g}, wider than ±{MAX_REL_HALF_WIDTH:.0%}; the prior's "
               f"{kept:.3g} agrees with the logs and is kept")
    else:  # keeping the prior would write a profile the logs rule out
        value, lo, hi, keep = q50, q05, q95, False
        why = (f"the logs rule out the prior's {kept:.3g} ({where}, {size:.1f} noise SDs) but leave it uncertain "
               f"in {q05:.3g}..{q95:.3g}, wider than ±{MAX_REL_HALF_WIDTH:.0%}: the profile takes the posterior's "
               f"median, which is not a confident value")
    return {"value": value, "low": lo, "high": hi, "identifiable": identifiable, "unit": p.unit, "prior": kept,
            "kept_prior": keep, "posterior": [q05, q50, q95], "effect": size, "most_visible_in": where, "why": why}


def _ruled_out_jointly(estimate: dict[str, Any], joint: float, improved: float, value: float) -> dict[str, Any]:
    """A parameter whose value fits the logs on its own but not together with the others:
    the profile takes ``value`` (from its 90 % interval, found by :func:`_search_together`).
    An identified parameter stays identified, with its interval, when that interval lies
    within ±25 % of ``value`` as well; any other is not a confident value, whether it was
    the prior's, the posterior's median, or an interval too wide for where the logs put it."""
    q05, q50, q95 = estimate["posterior"]
    together = (f"{joint:.1f} noise SDs² against {improved:.1f} with the values searched together in their "
                f"intervals")
    if estimate["identifiable"] and _narrow(q05, q95, value):
        why = (f"{estimate['why']}; the profile takes {value:.3g} from its interval, where it fits the logs "
               f"together with the other values (the posterior's median {q50:.3g} with them: {together})")
        return {**estimate, "value": value, "why": why}
    if estimate["identifiable"]:
        why = (f"{estimate['why']} (posterior median {q50:.3g}), but together with the other values the logs put it "
               f"at {value:.3g} ({together}), and its interval {q05:.3g}..{q95:.3g} is wider than "
               f"±{MAX_REL_HALF_WIDTH:.0%} of that: the profile takes {value:.3g}, which is not a confident value")
        return {**estimate, "value": value, "identifiable": False, "why": why}
    if estimate["kept_prior"]:
        was = f"the prior's {estimate['prior']:.3g} together with the other values misfits them"
    else:
        was = f"the posterior's median {q50:.3g} together with the other values misfits them"
    why = (f"the logs leave it uncertain ({q05:.3g}..{q95:.3g}, wider than ±{MAX_REL_HALF_WIDTH:.0%}), and {was} "
           f"({together}): the profile takes {value:.3g}, which is not a confident value")
    return {**estimate, "value": value, "low": q05, "high": q95, "kept_prior": False, "why": why}


SEARCH_BATCH = 4  #: candidates simulated together (the worker pool stays busy)


def _search_range(estimate: dict[str, Any]) -> tuple[float, float]:
    """Where :func:`_search_together` looks for a parameter's value: its 90 % interval,
    and for an identified parameter only the part of it from which the whole interval lies
    within ±:data:`MAX_REL_HALF_WIDTH` (the posterior's median is in that part), so that
    the value found is still a confident one. Unconstrained, the search once traded a true
    free speed of 4.5 rad/s (posterior median 4.48, interval 4.10..5.46) down to 4.30
    against a holding torque of 0.76 N·m (truth 0.3), from where the interval was too wide
    to call it identified."""
    q05, _, q95 = estimate["posterior"]
    if not estimate["identifiable"]:
        return q05, q95
    inner = 1.0 - 1e-9  # the ends themselves pass :func:`_narrow` despite rounding
    return (max(q05, q95 / (1.0 + MAX_REL_HALF_WIDTH * inner)),
            min(q95, q05 / (1.0 - MAX_REL_HALF_WIDTH * inner)))


def _search_together(fit: _Fit, names: Sequence[str], parameters: dict[str, dict[str, Any]],
                     profile: PhysicsProfile, noise: np.ndarray) -> dict[str, float]:
    """Values of the parameters ``names``, searched together inside their 90 % intervals
    (:func:`_search_range`; every other parameter as in ``profile``) for the simulated statistics nearest the
    logged ones: Optuna's TPE (multivariate: the values trade against each other) from the
    posterior's medians and the profile's values, every
    candidate simulated ``search_replicates`` times with the same seeds (common random
    numbers, so that candidates differ by their values, not their luck)."""
    import optuna
    from optuna.distributions import BaseDistribution, FloatDistribution

    settings = fit.settings
    space: dict[str, BaseDistribution] = {k: FloatDistribution(*_search_range(parameters[k])) for k in names}
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(sampler=optuna.samplers.TPESampler(
        seed=settings.seed, n_startup_trials=max(8, settings.search_trials // 4), multivariate=True))
    study.enqueue_trial({k: float(parameters[k]["posterior"][1]) for k in names})
    study.enqueue_trial({k: float(parameters[k]["value"]) for k in names})
    for start in range(0, settings.search_trials, SEARCH_BATCH):
        trials = [study.ask(space) for _ in range(min(SEARCH_BATCH, settings.search_trials - start))]
        r = settings.search_replicates
        runs = fit.simulator.run([(profile_at(profile, t.params), 60_000_000 + k) for t in trials for k in range(r)])
        for i, t in enumerate(trials):
            stats = np.array([fit.stats_of(f) for f in runs[i * r:(i + 1) * r]])
            study.tell(t, fit.misfit(stats, noise))
    return {k: float(v) for k, v in study.best_params.items()}


def _check_together(fit: _Fit, parameters: dict[str, dict[str, Any]], visible: list[str], profile: PhysicsProfile,
                    noise: np.ndarray, joint: float
                    ) -> tuple[dict[str, Any], tuple[PhysicsProfile, np.ndarray, list[list[np.ndarray]]] | None]:
    """The values ``visible`` (which show in the logs), checked together: searched in
    their intervals (:func:`_search_together`), then simulated on fresh seeds (no luck of
    the search's own); they replace the profile's in ``parameters`` when they lower the
    misfit ``joint`` by more than :data:`MIN_IMPROVEMENT`. Returns the check's record, and
    the new profile with its replicate runs if adopted."""
    found = _search_together(fit, visible, parameters, profile, noise)
    candidate = profile_at(profile, found)
    stats, runs = fit.replicate(candidate, 50_000_000)
    improved = fit.misfit(stats, noise)
    checked = {"parameters": visible, "misfit_kept": joint, "searched": found, "misfit_searched": improved,
               "adopted": improved < joint - MIN_IMPROVEMENT}
    if not checked["adopted"]:
        return checked, None
    for k in visible:
        parameters[k] = _ruled_out_jointly(parameters[k], joint, improved, found[k])
    return checked, (candidate, stats, runs)


def calibrate(traces: Sequence[Trace], tracks: Sequence[Track], prior: PhysicsProfile, name: str,
              simulator: Simulator, settings: Settings | None = None,
              say: Callable[[str], None] = lambda line: None,
              more: Callable[[int], None] = lambda n: None) -> Calibration:
    """Fit ``prior``'s :data:`PARAMETERS` to the logged ``tracks`` of ``traces`` (see the
    module docs). ``simulator`` runs (and caches) the simulations; ``more`` is told when a
    check adds simulations to those of :meth:`Settings.rounds` (a progress bar's total)."""
    settings = settings or Settings()
    logged = [step_features(tr, tk) for tr, tk in zip(traces, tracks, strict=True)]
    observed = statistics(logged, settings.spreads)
    if not observed:
        raise CalibrationError(f"the logs have fewer than {MIN_STEPS} steps of every kind of command: nothing to fit "
                               "(run the identification trials, tumblebot bench excite)")
    fit = _Fit(observed, prior, simulator, settings)
    sizes = settings.rounds()
    say(f"round 1 of {len(sizes)}: the prior box, {sizes[0]} simulated trial sets and {settings.replicates} replicates")
    prior_stats, prior_runs = fit.replicate(prior, 10_000_000)
    noise1 = np.var(prior_stats, axis=0, ddof=1) + 1e-12
    u1, y = fit.design(sizes[0], fit.box1, settings.seed, 0)
    points = fit.values(u1, fit.box1)  # every simulated design point so far, as parameter values
    emulator = Emulator.fit(u1, y)
    values, w = fit.posterior(emulator, fit.box1, settings.seed + 1)
    centre = fit.median(values, w)
    centre_u = fit.units(np.array([[centre[p.name] for p in fit.params]]), fit.box1)[0]
    effects = fit.effects(emulator, noise1, centre_u)

    for r, (size, (tail, pad)) in enumerate(zip(sizes[1:], ZOOMS, strict=False), start=2):
        box = fit.zoom(values, w, tail, pad)
        say(f"round {r} of {len(sizes)}: the posterior's box, {size} simulated trial sets")
        u_new, y_new = fit.design(size, box, settings.seed + 2 * (r - 1), 30_000_000 * (r - 1))
        mask = fit.inside(points, box)  # earlier rounds' points inside the new box help too
        emulator = Emulator.fit(np.vstack([u_new, fit.units(points[mask], box)]), np.vstack([y_new, y[mask]]))
        points, y = np.vstack([points, fit.values(u_new, box)]), np.vstack([y, y_new])
        values, w = fit.posterior(emulator, box, settings.seed + 2 * r - 1)

    parameters = {p.name: _estimate(p, prior, _weighted_quantiles(values[:, j], w, [0.05, 0.5, 0.95]),
                                    effects[p.name], fit.box1[j]) for j, p in enumerate(fit.params)}
    profile = profile_at(prior, {k: v["value"] for k, v in parameters.items() if not v["kept_prior"]}, name)
    say("checking the fit: replicate simulations under the fitted profile")
    # twice the replicates: their scatter is the yardstick of every misfit from here on
    fitted_stats, fitted_runs = fit.replicate(profile, 40_000_000, times=2)
    noise = np.var(fitted_stats, axis=0, ddof=1) + 1e-12

    misfit = fit.misfit
    # Each value agrees with the logs on its own; together they may not (a servo's stall
    # torque and the floor's friction both set how far a spin goes, and the medians of a
    # posterior whose parameters trade against each other need not lie on its ridge).
    visible = [k for k, v in parameters.items() if v["effect"] >= MIN_EFFECT]
    joint = misfit(fitted_stats, noise)
    checked: dict[str, Any] | None = None  #: the check of the values together, when it ran
    if visible:
        say("checking the fit: searching the values together in their intervals")
        more(settings.search_simulations())
        checked, adopted = _check_together(fit, parameters, visible, profile, noise, joint)
        if adopted is not None:
            profile, fitted_stats, fitted_runs = adopted

    summary = {"trials": len(traces), "steps": int(sum(len(f) for f in logged)),
               "simulated_sets": simulator.simulated, "effective_samples": float(1.0 / (w ** 2).sum()),
               "not_fitted": {k: getattr(prior, k) for k in NOT_FITTED},
               "statistics": {n: {"logged": float(fit.s_obs[i]), "prior": float(prior_stats[:, i].mean()),
                                  "fitted": float(fitted_stats[:, i].mean()), "noise_sd": float(math.sqrt(noise[i]))}
                              for i, n in enumerate(fit.names)},
               "misfit_prior": misfit(prior_stats, noise1), "misfit_fitted": misfit(fitted_stats, noise),
               "kept_values_checked": checked}
    features = {"logged": logged, "prior": [f for run in prior_runs for f in run],
                "fitted": [f for run in fitted_runs for f in run]}
    return Calibration(profile, prior, parameters, summary, features)


# ----------------------------------------------------------------------------- the picture
def plot(cal: Calibration, path: Path) -> None:
    """Logged against simulated per-step motion, under the prior and the fitted profile:
    per kind of command, the distribution of step distances and turns."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    logged = np.vstack(cal.features["logged"])
    kinds = [c for c in range(len(CLASSES)) if (logged[:, 0] == c).sum() >= MIN_STEPS]
    fig, axes = plt.subplots(2, len(kinds), figsize=(3.2 * len(kinds), 5.6), squeeze=False)
    series = (("logged", "black", "logged"), ("prior", "tab:red", f"prior ({cal.prior.name})"),
              ("fitted", "tab:blue", f"fitted ({cal.profile.name})"))
    for col, c in enumerate(kinds):
        for row, (feature, label) in enumerate(((1, "distance per step (m)"), (2, "turn per step (rad)"))):
            ax = axes[row][col]
            data = {key: np.vstack(cal.features[key]) for key, _, _ in series}
            values = [d[d[:, 0] == c, feature] for d in data.values()]
            hi = max(float(v.max()) for v in values if len(v)) or 1.0
            bins = np.linspace(0.0, hi * 1.05, 16)
            for (key, colour, text), v in zip(series, values, strict=True):
                ax.hist(v, bins=bins, density=True, histtype="step" if key != "logged" else "stepfilled",
                        color=colour, alpha=0.35 if key == "logged" else 1.0, lw=1.6, label=text)
            ax.set_xlabel(label, fontsize=8)
            if row == 0:
                kind = "drives from rest" if CLASSES[c] == "start" else f"{CLASSES[c]} steps"
                ax.set_title(f"{kind} ({int((logged[:, 0] == c).sum())} logged)", fontsize=9)
            ax.tick_params(labelsize=7)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"calibration: {cal.fit['trials']} trials; misfit (mean squared, in noise SDs) "
                 f"{cal.fit['misfit_prior']:.1f} under the prior, {cal.fit['misfit_fitted']:.1f} fitted", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
