"""Design optimisation (thesis §2.6): Bayesian optimisation of ``w = (x, y, z, l)``.

The objective of a design is the thesis's: the mean over a batch of ``B`` episodes of
``Σ_i λ_i·f_i`` with ``f = R / (e(w) + 1)^ξ`` (:mod:`tumblebot.sim.objective`), each task's
``R`` coming from its bundled ONNX policy. Optuna runs the search: designs drawn at random
for the start-up trials, then its Gaussian-process sampler with log expected improvement
(``qLogEI`` over the designs other workers are still evaluating). Studies live in any
Optuna RDB storage: an SQLite file by default, PostgreSQL or MySQL to share a study
between machines. Every process pointed at the same study cooperates on it.

Noise. ``R`` is random (starts, masses, friction, motor noise, latency), so a design's
objective is a batch mean with a standard error. Three things keep that noise from
steering the search:

* common random numbers: episode ``i`` is the same episode for every design
  (:mod:`tumblebot.sim.runner`), so differences between designs are not drowned by
  differences between episodes;
* the GP fits a noise variance (``deterministic_objective=False``) rather than
  interpolating the observations;
* the reported optimum is the best design evaluated on the *full* batch, and the report
  re-evaluates it on fresh episodes, so a lucky batch does not crown it.

Recipes (:class:`Recipe`): ``standard`` (every trial a full batch), ``thesis`` (exactly
the thesis's schedule: 1000 random designs, 1000 EI iterations, ``B = 240``) and
``efficient`` (trials screened on a small batch; the most promising designs are promoted
to the full batch, reusing their screening episodes).

Infeasible designs. Legs shorter than the pivot radius (``l < r``) cannot lift the body
past its balance point (SPEC §3). Such trials cost no episodes; they are recorded with the
reason in ``user_attrs["infeasible"]``, told to Optuna with the worst feasible value so far,
and carry the constraint ``r - l <= 0`` so the GP sampler learns where the boundary is (a
failed trial would be invisible to it, and it would propose the same corner again). They
are never reported as an optimum. A NaN result is recorded as a failed, flagged trial.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import socket
import threading
import time
import warnings
import weakref
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tumblebot.sim.constants import STALL_TORQUE
from tumblebot.sim.design import BOUNDS, PARAMETERS, Design
from tumblebot.sim.errors import SimError, UnknownTaskError
from tumblebot.sim.evaluate import Controller, Servo
from tumblebot.sim.objective import VARIANTS, Variant, wrap_reward
from tumblebot.sim.power import energy_per_metre
from tumblebot.sim.tasks import get_task

if TYPE_CHECKING:
    import optuna

    from tumblebot.sim.runner import EpisodeRunner

#: Key of the study user attribute that records what a study optimises.
STUDY_KEY = "tumblebot"
PROMOTED_PREFIX = "promoted:"
DEFAULT_STORAGE = "sqlite:///tumblebot-optuna.db"


class OptimizeError(SimError):
    """A bad optimisation request: bad tasks or weights, a storage that cannot be opened,
    or a study that was created for a different objective."""


class StopRequested(Exception):
    """Raised at a safe point after Ctrl-C (or SIGTERM) asked the run to stop."""


class StopFlag:
    """Ctrl-C and SIGTERM only set this flag; the optimiser looks at it at safe points
    (between episodes, before asking for a trial) and stops there, marking an unfinished
    trial interrupted so it is redone. Use :meth:`installed` around the work."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def __call__(self) -> bool:
        return self._event.is_set()

    def set(self) -> None:
        self._event.set()

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopFlag]:
        """Route SIGINT and SIGTERM to this flag while the block runs (main thread only)."""
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        previous = {sig: signal.signal(sig, lambda _sig, _frame: self.set())
                    for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield self
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


# --------------------------------------------------------------------------- objective
def parse_tasks(text: str) -> dict[str, float]:
    """Parse ``"nav-flat=1,incline=0.5"`` into task → weight (a bare name weighs 1)."""
    weights: dict[str, float] = {}
    if not text.strip():
        raise OptimizeError("--tasks is empty; give e.g. nav-flat=1,incline=0.5")
    for part in text.split(","):
        name, sep, raw = part.partition("=")
        name = name.strip()
        if not name:
            raise OptimizeError(f"--tasks {text!r}: an entry has no task name")
        try:
            task = get_task(name).name
        except UnknownTaskError as exc:
            raise OptimizeError(f"--tasks: {exc}") from None
        if task in weights:
            raise OptimizeError(f"--tasks: task {task!r} is given twice")
        if sep:
            try:
                weight = float(raw)
            except ValueError:
                raise OptimizeError(f"--tasks: weight {raw.strip()!r} of {task} is not a number") from None
        else:
            weight = 1.0
        if not math.isfinite(weight) or weight < 0:
            raise OptimizeError(f"--tasks: weight {weight} of {task} must be a finite number >= 0")
        weights[task] = weight
    if not any(weights.values()):
        raise OptimizeError("--tasks: at least one weight must be positive")
    return weights


def parse_xi(text: str) -> float:
    """ξ from a command line: a number ``>= 0``, or ``inf`` (minimise ``e(w)`` alone)."""
    if text.strip().lower() in ("inf", "infinity", "∞"):
        return math.inf
    try:
        xi = float(text)
    except ValueError:
        raise OptimizeError(f"--xi {text!r} is not a number (use a value >= 0, or inf)") from None
    if math.isnan(xi) or xi < 0:
        raise OptimizeError(f"--xi {text!r} must be >= 0 (or inf)")
    return xi


def format_xi(xi: float) -> str:
    return "inf" if math.isinf(xi) else f"{xi:g}"


@dataclass(frozen=True)
class Objective:
    """What a study maximises: weighted tasks, ``ξ`` and the wrapper variant."""

    weights: dict[str, float]
    xi: float
    variant: Variant = "thesis"

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise OptimizeError(f"wrapper variant {self.variant!r} must be one of {VARIANTS}")

    @property
    def tasks(self) -> list[str]:
        """Tasks that need episodes (positive weight; none when ``ξ = ∞``)."""
        if math.isinf(self.xi):
            return []
        return [t for t, wt in self.weights.items() if wt > 0]

    def per_episode(self, R: dict[str, np.ndarray], e: float) -> np.ndarray:
        """``Σ_i λ_i·f_i`` of each episode of a batch (``-e`` when ``ξ = ∞``)."""
        if math.isinf(self.xi):
            return np.array([-e])
        n = len(next(iter(R.values())))
        total = np.zeros(n)
        for task in self.tasks:
            total += self.weights[task] * np.array([wrap_reward(float(r), e, self.xi, self.variant) for r in R[task]])
        return total

    def describe(self) -> str:
        tasks = ",".join(f"{t}={wt:g}" for t, wt in self.weights.items())
        return f"{tasks} ξ={format_xi(self.xi)} ({self.variant} wrapper)"


# --------------------------------------------------------------------------- recipes
@dataclass(frozen=True)
class Recipe:
    """How many designs, with how many episodes each.

    Attributes:
        name: ``standard``, ``thesis`` or ``efficient``.
        trials: designs to evaluate (infeasible ones included).
        batch: the full batch ``B``, episodes per task for a final verdict on a design.
        startup: feasible designs drawn at random before the GP takes over.
        screen_batch: episodes per task for an ordinary trial (``batch`` unless efficient).
        promote_every: efficient only: after every this many trials, the best design not yet
            evaluated on the full batch gets the remaining ``batch - screen_batch`` episodes.
        final_promotions: efficient only: designs promoted when the trials are done.
    """

    name: str
    trials: int
    batch: int
    startup: int
    screen_batch: int
    promote_every: int = 0
    final_promotions: int = 0

    def __post_init__(self) -> None:
        if self.trials < 1:
            raise OptimizeError(f"--trials {self.trials} must be at least 1")
        if self.batch < 1:
            raise OptimizeError(f"--batch {self.batch} must be at least 1 episode")
        if not self.startup >= 0:
            raise OptimizeError(f"--startup {self.startup} must be >= 0")
        if not 1 <= self.screen_batch <= self.batch:
            raise OptimizeError(f"screening batch {self.screen_batch} must be between 1 and --batch {self.batch}")

    @classmethod
    def make(cls, name: str, trials: int | None, batch: int | None, startup: int | None = None) -> Recipe:
        """Build a named recipe; ``thesis`` fixes every number and refuses others."""
        if name == "thesis":
            if any(v is not None and v != fixed for v, fixed in ((trials, 2000), (batch, 240), (startup, 1000))):
                raise OptimizeError("--recipe thesis fixes --trials 2000 --batch 240 --startup 1000; "
                                    "use --recipe standard or efficient for other numbers")
            return cls("thesis", 2000, 240, 1000, 240)
        if trials is None or batch is None:
            raise OptimizeError(f"--recipe {name} needs --trials and --batch")
        if trials < 1:
            raise OptimizeError(f"--trials {trials} must be at least 1")
        if batch < 1:
            raise OptimizeError(f"--batch {batch} must be at least 1 episode")
        if startup is None:
            startup = max(1, min(trials // 2, 20))
        if name == "standard":
            return cls("standard", trials, batch, startup, batch)
        if name == "efficient":
            screen = max(min(batch, 4), batch // 15)
            return cls("efficient", trials, batch, startup, screen, promote_every=10,
                       final_promotions=min(3, trials))
        raise OptimizeError(f"--recipe {name!r} must be standard, thesis or efficient")


@dataclass
class StudyConfig:
    """What a study was created for, stored in its user attributes; a command that asks
    for something else is refused before anything is written."""

    weights: dict[str, float]
    xi: float | str  # "inf" in JSON
    variant: str
    recipe: str
    batch: int
    screen_batch: int
    startup: int
    seed: int
    policies: dict[str, str] = field(default_factory=dict)  # task → SHA-256 of the ONNX file
    #: what drove the episodes: "policy" (each task's bundled ONNX policy), "thesis-policy"
    #: (each task's bundled policy that sees only the thesis's 9-number observation), or a
    #: gait name (``goto``, the closed-loop navigation controller, or a scripted gait).
    #: Studies made before this field existed load as "policy".
    controller: str = "policy"
    motor_model: str = "dc"  #: the servo of every episode (SPEC: part of the objective)
    stall_torque: float = STALL_TORQUE

    @classmethod
    def of(cls, objective: Objective, recipe: Recipe, seed: int, policies: dict[str, str],
           controller: str = "policy", servo: Servo | None = None) -> StudyConfig:
        xi: float | str = "inf" if math.isinf(objective.xi) else objective.xi
        servo = servo or Servo()
        return cls(dict(objective.weights), xi, objective.variant, recipe.name, recipe.batch, recipe.screen_batch,
                   recipe.startup, seed, policies, controller, servo.model, servo.stall_torque)

    def servo(self) -> Servo:
        return Servo.of(self.motor_model, self.stall_torque)

    def objective(self) -> Objective:
        xi = math.inf if self.xi == "inf" else float(self.xi)
        return Objective(dict(self.weights), xi, self.variant)  # type: ignore[arg-type]

    def differences(self, other: StudyConfig) -> list[str]:
        """What differs in the objective or its noise (``startup`` may change between runs)."""
        mine, theirs = asdict(self), asdict(other)
        return [f"{k}: study has {mine[k]!r}, command asks for {theirs[k]!r}"
                for k in mine if k != "startup" and mine[k] != theirs[k]]


# --------------------------------------------------------------------------- storage
def open_storage(url: str, writable: bool = False, must_exist: bool = False) -> Any:
    """An Optuna RDB storage for ``url`` (``sqlite:///file.db``, ``postgresql://…``), with
    heartbeats so a trial whose process was killed is failed and not counted forever.

    For SQLite files, checked before anything is opened: ``must_exist`` refuses a file
    that is not there (a report never creates an empty database from a typo), and
    ``writable`` refuses a file or folder this process cannot write (a study is written)."""
    import optuna
    from optuna.storages import RDBStorage

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    if "://" not in url:
        raise OptimizeError(f"--storage {url!r} is not a database URL (e.g. sqlite:///study.db, "
                            "postgresql://user@host/db)")
    if url.startswith("sqlite:///"):
        path = Path(url[len("sqlite:///"):])
        if str(path) and str(path) != ":memory:":
            if not path.parent.exists():
                raise OptimizeError(f"--storage {url!r}: folder {path.parent} does not exist")
            if must_exist and not path.is_file():
                raise OptimizeError(f"--storage {url!r}: there is no database file {path}")
            if writable and path.exists() and not os.access(path, os.R_OK | os.W_OK):
                raise OptimizeError(f"--storage {url!r}: the database file {path} is not writable by this user")
            if writable and not os.access(path.parent, os.W_OK | os.X_OK):
                raise OptimizeError(f"--storage {url!r}: folder {path.parent} is not writable (SQLite writes a "
                                    "journal beside the database)")
    engine_kwargs: dict[str, Any] = {}
    if url.startswith("sqlite"):
        engine_kwargs = {"connect_args": {"timeout": 60}}  # several processes share one file
    for attempt in range(5):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                return RDBStorage(url, engine_kwargs=engine_kwargs, heartbeat_interval=10, grace_period=60)
        except Exception as exc:  # SQLAlchemy raises many types; all mean "cannot open"
            text = str(exc)
            # Workers started together on an empty database race to create the schema; the
            # loser sees a duplicate-key (PostgreSQL) or UNIQUE-constraint (SQLite, on
            # alembic_version) error and finds the tables on its next try.
            if attempt < 4 and any(m in text for m in ("duplicate key", "already exists", "UNIQUE constraint")):
                time.sleep(0.5 + attempt)
                continue
            first = text.strip().splitlines()[0] if text.strip() else type(exc).__name__
            raise OptimizeError(f"--storage {url!r} cannot be opened: {first}") from None
    raise AssertionError("unreachable")


def load_config(study: optuna.Study) -> StudyConfig | None:
    raw = study.user_attrs.get(STUDY_KEY)
    return StudyConfig(**raw) if raw else None


def load_study(storage: Any, name: str) -> optuna.Study:
    import optuna

    try:
        return optuna.load_study(study_name=name, storage=storage)
    except KeyError:
        known = [s.study_name for s in optuna.get_all_study_summaries(storage, include_best_trial=False)]
        raise OptimizeError(f"study {name!r} does not exist in this storage; studies: "
                            f"{', '.join(known) or 'none'}") from None


def open_study(storage: Any, name: str, config: StudyConfig) -> optuna.Study:
    """Create the study, or load it after checking it was made for the same objective."""
    import optuna

    study = optuna.create_study(study_name=name, storage=storage, direction="maximize", load_if_exists=True)
    _STORAGES[study] = storage
    existing = load_config(study)
    if existing is None:
        if study.trials:
            raise OptimizeError(f"study {name!r} exists but was not made by tumblebot optimize; "
                                "choose another --study")
        study.set_user_attr(STUDY_KEY, asdict(config))
        return study
    diff = existing.differences(config)
    if diff:
        raise OptimizeError(f"study {name!r} was created for a different objective; nothing was changed. "
                            + "; ".join(diff) + ". Use another --study, or repeat the original options.")
    return study


# --------------------------------------------------------------------------- sampling
class TrialNumberSampler:
    """Start-up designs drawn from ``SeedSequence([seed, trial.number])``: the same designs
    whichever process runs which trial, so a study is reproducible with any worker count."""

    def __init__(self, seed: int) -> None:
        self.seed = seed

    def value(self, trial_number: int, name: str, low: float, high: float) -> float:
        ss = np.random.SeedSequence([self.seed, trial_number, PARAMETERS.index(name)])
        return float(np.random.default_rng(ss).uniform(low, high))


def make_sampler(recipe: Recipe, seed: int, process_salt: int) -> optuna.samplers.BaseSampler:
    import optuna
    from optuna.distributions import BaseDistribution, FloatDistribution

    base = TrialNumberSampler(seed)

    class _Startup(optuna.samplers.RandomSampler):
        def sample_independent(self, study: optuna.Study, trial: optuna.trial.FrozenTrial, param_name: str,
                               param_distribution: BaseDistribution) -> Any:
            assert isinstance(param_distribution, FloatDistribution)
            return base.value(trial.number, param_name, param_distribution.low, param_distribution.high)

    return optuna.samplers.GPSampler(seed=int(np.random.SeedSequence([seed, process_salt]).generate_state(1)[0]),
                                     independent_sampler=_Startup(seed=seed), n_startup_trials=recipe.startup,
                                     deterministic_objective=False, warn_independent_sampling=False)


# --------------------------------------------------------------------------- trials
def _is_infeasible(t: optuna.trial.FrozenTrial) -> bool:
    return "infeasible" in t.user_attrs


def _imputed_value(study: optuna.Study) -> float:
    """The value an infeasible design is told with: the worst feasible value so far (0 before
    any). With the constraint ``r - l <= 0`` this keeps the GP out of the infeasible region
    without inventing episodes; the design is flagged and never reported as an optimum."""
    from optuna.trial import TrialState

    values = [t.value for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
              if t.value is not None and not _is_infeasible(t)]
    return min(values) if values else 0.0


#: Name of the Optuna constraint ``r - l`` (feasible when <= 0) set on every trial.
CONSTRAINT = "pivot_radius_minus_leg"


def counted_trials(study: optuna.Study) -> int:
    """Trials that count toward ``--trials``: finished, infeasible, or running in some worker.
    Interrupted trials (Ctrl-C, a killed process) do not count; they are redone."""
    from optuna.trial import TrialState

    n = 0
    for t in study.get_trials(deepcopy=False):
        if t.state in (TrialState.COMPLETE, TrialState.RUNNING) or (t.state == TrialState.FAIL and _is_infeasible(t)):
            n += 1  # (NaN results are failed and flagged infeasible; they count too)
    return n


def trial_design(t: optuna.trial.FrozenTrial) -> Design:
    return Design(*(t.params[n] for n in PARAMETERS))


def promotions(study: optuna.Study) -> dict[int, dict[str, Any]]:
    """Full-batch results of promoted trials (efficient recipe), by trial number."""
    out: dict[int, dict[str, Any]] = {}
    for key, value in study.user_attrs.items():
        if key.startswith(PROMOTED_PREFIX) and isinstance(value, dict) and "value" in value:
            out[int(key[len(PROMOTED_PREFIX):])] = value
    return out


@dataclass
class Candidate:
    """A design with its full-batch result."""

    trial: int
    design: Design
    value: float
    batch: int
    R: dict[str, list[float]]
    e: float


def full_batch_results(study: optuna.Study) -> list[Candidate]:
    """Every design evaluated on the study's full batch (trials and promotions)."""
    from optuna.trial import TrialState

    config = load_config(study)
    if config is None:
        raise OptimizeError(f"study {study.study_name!r} was not made by tumblebot optimize")
    promoted = promotions(study)
    out: list[Candidate] = []
    for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
        if _is_infeasible(t):
            continue
        if t.number in promoted:
            p = promoted[t.number]
            out.append(Candidate(t.number, trial_design(t), float(p["value"]), int(p["batch"]), p["R"],
                                 float(t.user_attrs["e"])))
        elif int(t.user_attrs.get("batch", 0)) >= config.batch or t.user_attrs.get("batch") == 0:
            assert t.value is not None
            out.append(Candidate(t.number, trial_design(t), float(t.value), int(t.user_attrs.get("batch", 0)),
                                 t.user_attrs.get("R", {}), float(t.user_attrs["e"])))
    return out


def best_candidate(study: optuna.Study) -> Candidate | None:
    """The study's optimum: the best design on the full batch (or None before any)."""
    cands = full_batch_results(study)
    return max(cands, key=lambda c: c.value) if cands else None


def study_controllers(controller: str, tasks: list[str], allow_servo_mismatch: bool = False,
                      servo: Servo | None = None) -> dict[str, Controller]:
    """``controller`` ``"policy"`` (each task's bundled ONNX policy), ``"thesis-policy"``
    (the bundled ones with the thesis observation) or a gait name (``goto`` included), as
    a task → :class:`Controller` map, each checked for its task and ``servo`` (here,
    before a study is opened or written)."""
    if controller in ("policy", "thesis-policy"):
        out = {t: Controller("onnx", str(p), allow_servo_mismatch)
               for t, p in bundled_policies(tasks, thesis=controller == "thesis-policy").items()}
    else:
        out = {t: Controller.of_gait(controller) for t in tasks}
    for t, c in out.items():
        c.check(t, servo)
    return out


def bundled_policies(tasks: list[str], thesis: bool = False) -> dict[str, Path]:
    """The bundled ONNX policy of each task (with ``thesis``, the one that sees only the
    thesis observation, :func:`~tumblebot.sim.policy.bundled_policy`)."""
    from tumblebot.sim.policy import PolicyError, bundled_policy

    out = {t: bundled_policy(t, "thesis" if thesis else None) for t in tasks}
    missing = [t for t, path in out.items() if not path.is_file()]
    if missing:
        raise PolicyError(f"no bundled policy for {', '.join(missing)} yet (policies/TASK.onnx); "
                          "train and export one first (tumblebot train / tumblebot export)")
    return out


def format_best(best: Candidate | None, objective: Objective) -> str:
    """The optimum as a small table, for the terminal."""
    if best is None:
        return "no design has been evaluated on the full batch yet"
    w = best.design
    lines = [f"best robot: trial {best.trial}, {best.batch} episodes per task",
             "  x = {:.3f} m   y = {:.3f} m   z = {:.3f} m   l = {:.3f} m".format(*w.as_tuple()),
             f"  e(w) = {best.e:.3f} W/m   objective = {best.value:.5g}"]
    for task, R in best.R.items():
        lines.append(f"  {task}: mean R = {float(np.mean(R)):.3f} (weight {objective.weights[task]:g})")
    return "\n".join(lines)


@dataclass
class Progress:
    """What :func:`optimize` reports after each trial."""

    done: int
    total: int
    episodes: int
    best: Candidate | None
    last_value: float | None
    last_state: str


def _evaluate(objective: Objective, runner: EpisodeRunner | None, design: Design, start: int, stop: int,
              seed: int, on_result: Callable[[], object] | None = None
              ) -> tuple[dict[str, list[float]], float, np.ndarray]:
    e = energy_per_metre(design)
    if not objective.tasks:
        return {}, e, objective.per_episode({}, e)
    if runner is None:
        raise OptimizeError("this objective needs episodes, but no episode runner was given")
    R = runner.run(design, objective.tasks, start, stop, seed, on_result=on_result)
    return {t: r.tolist() for t, r in R.items()}, e, objective.per_episode(R, e)


#: Kernel width of the screening smoother, as a fraction of each parameter's range.
SMOOTHING_WIDTH = 0.08


def screen_scores(study: optuna.Study, objective: Objective) -> dict[int, float]:
    """Screened trials ranked without trusting any single small batch.

    Only ``R`` is noisy; ``e(w)`` is exact. So each task's mean ``R`` is smoothed over
    neighbouring designs (a Gaussian kernel, :data:`SMOOTHING_WIDTH` of each range, each
    trial weighted by its episodes), and the objective is recomputed from the smoothed
    ``R`` and the design's exact ``e``. A lucky 4-episode batch then no longer wins a
    promotion on its own: it needs neighbours that agree.
    """
    from optuna.trial import TrialState

    trials = [t for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
              if t.value is not None and not _is_infeasible(t) and t.user_attrs.get("R")]
    if not trials:
        return {}
    span = np.array([BOUNDS[n][1] - BOUNDS[n][0] for n in PARAMETERS])
    X = np.array([[t.params[n] for n in PARAMETERS] for t in trials]) / span
    d2 = ((X[:, None, :] - X[None, :, :]) ** 2).sum(-1)
    K = np.exp(-d2 / (2 * SMOOTHING_WIDTH ** 2))
    scores: dict[int, float] = {}
    for task in objective.tasks:
        n = np.array([len(t.user_attrs["R"][task]) for t in trials], dtype=float)
        mean = np.array([float(np.mean(t.user_attrs["R"][task])) for t in trials])
        smooth = (K * n) @ mean / (K @ n)
        for t, r in zip(trials, smooth, strict=True):
            e = float(t.user_attrs["e"])
            scores[t.number] = scores.get(t.number, 0.0) + objective.weights[task] * wrap_reward(
                float(r), e, objective.xi, objective.variant)
    return scores


def _promote(study: optuna.Study, objective: Objective, recipe: Recipe, runner: EpisodeRunner | None,
             seed: int, on_result: Callable[[], object] | None = None) -> int:
    """Extend the most promising not-yet-promoted screened trial (by :func:`screen_scores`)
    to the full batch. Returns episodes run."""
    done = promotions(study)
    pending = {int(k[len("promoting:"):]) for k, v in study.user_attrs.items() if k.startswith("promoting:") and v}
    scores = {n: v for n, v in screen_scores(study, objective).items() if n not in done and n not in pending}
    if not scores:
        return 0
    t = study.trials[max(scores, key=lambda n: scores[n])]
    study.set_user_attr(f"promoting:{t.number}", True)
    design = trial_design(t)
    try:
        more, e, _ = _evaluate(objective, runner, design, recipe.screen_batch, recipe.batch, seed, on_result)
    except BaseException:
        with contextlib.suppress(Exception):
            study.set_user_attr(f"promoting:{t.number}", False)  # let it be promoted again later
        raise
    R = {task: list(t.user_attrs["R"][task]) + more[task] for task in objective.tasks}
    value = float(np.mean(objective.per_episode({k: np.array(v) for k, v in R.items()}, e)))
    study.set_user_attr(f"{PROMOTED_PREFIX}{t.number}", {"value": value, "batch": recipe.batch, "R": R,
                                                        "screen_value": t.value})
    return (recipe.batch - recipe.screen_batch) * len(objective.tasks)


def optimize(study: optuna.Study, objective: Objective, recipe: Recipe, runner: EpisodeRunner | None, seed: int,
             on_progress: Callable[[Progress], None] | None = None, episode_budget: int | None = None,
             should_stop: Callable[[], bool] | None = None) -> Progress:
    """Run trials until the study holds ``recipe.trials`` of them (counting other workers'),
    or until it has spent ``episode_budget`` episodes (the efficient recipe keeps enough of
    the budget back for its final promotions).

    ``should_stop`` (e.g. a :class:`StopFlag` that Ctrl-C sets) is looked at before each
    trial and after every episode; when it says stop, the trial in progress is marked
    interrupted (it will be redone) and :class:`StopRequested` is raised. The study stays
    consistent and the same call resumes it. A ``KeyboardInterrupt`` (Ctrl-C with no flag
    installed) is handled the same way.

    While a trial runs, its heartbeat is recorded from this loop (after every episode, at
    most every few seconds), so a trial of a process that was killed is failed by
    :func:`optuna.storages.fail_stale_trials` and redone.
    """
    import optuna

    # Seeded by the study's size at start: a rerun is reproducible, and workers joining a
    # study later get other seeds (workers started together differ through qLogEI, which
    # conditions on each other's running trials).
    sampler = make_sampler(recipe, seed, process_salt=len(study.trials))
    study.sampler = sampler
    distributions: dict[str, optuna.distributions.BaseDistribution] = {
        n: optuna.distributions.FloatDistribution(*BOUNDS[n]) for n in PARAMETERS}
    episodes = 0
    last_value: float | None = None
    last_state = ""
    n_tasks = len(objective.tasks)
    spent_before = episode_count(study) if episode_budget is not None else 0
    reserve = recipe.final_promotions * (recipe.batch - recipe.screen_batch) * n_tasks

    def affordable(cost: int, keep: int = 0) -> bool:
        return episode_budget is None or spent_before + episodes + cost + keep <= episode_budget

    def progress() -> Progress:
        p = Progress(counted_trials(study), recipe.trials, episodes, best_candidate(study), last_value, last_state)
        if on_progress is not None:
            on_progress(p)
        return p

    stop = should_stop or (lambda: False)

    def safe_point() -> None:
        if stop():
            raise StopRequested

    promotion = (recipe.batch - recipe.screen_batch) * n_tasks
    while True:
        safe_point()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            optuna.storages.fail_stale_trials(study)  # trials of killed workers: failed, redone
        if counted_trials(study) >= recipe.trials or not affordable(recipe.screen_batch * n_tasks, reserve):
            break
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Heartbeat of storage")  # we record the heartbeat ourselves
            trial = study.ask(distributions)
        try:  # nothing between ask() and here can be interrupted: signals only set the flag
            beat = _Heartbeat(study, trial.number, then=safe_point)
            beat()
            value, added = _run_trial(study, trial, objective, recipe, runner, seed, beat)
        except BaseException:
            _mark_interrupted(study, trial)
            raise
        episodes += added
        last_value, last_state = value, "complete" if value is not None else "infeasible"
        if recipe.promote_every and objective.tasks and trial.number >= recipe.startup \
                and (trial.number + 1) % recipe.promote_every == 0 and affordable(promotion, reserve):
            episodes += _promote(study, objective, recipe, runner, seed, safe_point)
        progress()
    if objective.tasks:
        for _ in range(recipe.final_promotions):
            safe_point()
            if _top_is_promoted(study, objective, recipe.final_promotions) or not affordable(promotion):
                break
            episodes += _promote(study, objective, recipe, runner, seed, safe_point)
    return progress()


class _Heartbeat:
    """Records a running trial's heartbeat through the storage's public
    ``record_heartbeat``, at most every :data:`HEARTBEAT_EVERY` seconds (no thread: it is
    called from the loop, after every episode, so nothing is left running at exit), then
    calls ``then`` (the stop check)."""

    def __init__(self, study: optuna.Study, number: int, then: Callable[[], None] = lambda: None) -> None:
        self.then = then
        self.storage = _storage_of(study)
        self.enabled = callable(getattr(self.storage, "record_heartbeat", None))
        self.trial_id = (self.storage.get_trial_id_from_study_id_trial_number(
            self.storage.get_study_id_from_name(study.study_name), number) if self.enabled else -1)
        self.last = -math.inf

    def __call__(self) -> None:
        now = time.monotonic()
        if self.enabled and now - self.last >= HEARTBEAT_EVERY:
            self.last = now
            self.storage.record_heartbeat(self.trial_id)
        self.then()


#: Seconds between heartbeats of a running trial (the storage's grace period is 60 s).
HEARTBEAT_EVERY = 5.0


#: The storage each study was opened from (Optuna has no public accessor for it).
_STORAGES: weakref.WeakKeyDictionary[optuna.Study, Any] = weakref.WeakKeyDictionary()


def _storage_of(study: optuna.Study) -> Any:
    storage = _STORAGES.get(study)
    if storage is None:
        raise OptimizeError("open studies with tumblebot.sim.optimize.open_study (it keeps the storage)")
    return storage


def _mark_interrupted(study: optuna.Study, trial: optuna.Trial) -> None:
    """A trial this process left unfinished (Ctrl-C, a crash): failed and flagged, so it is
    redone, unless it was already told."""
    from optuna.trial import TrialState

    with contextlib.suppress(Exception):
        frozen = [t for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))
                  if t.number == trial.number]
        if frozen:
            trial.set_user_attr("interrupted", True)
            study.tell(trial, state=TrialState.FAIL)


def _run_trial(study: optuna.Study, trial: optuna.Trial, objective: Objective, recipe: Recipe,
               runner: EpisodeRunner | None, seed: int, on_result: Callable[[], object] | None = None
               ) -> tuple[float | None, int]:
    """Evaluate one asked trial and tell its result. Returns (value or None, episodes run)."""
    from optuna.trial import TrialState

    design = Design(*(trial.params[n] for n in PARAMETERS))
    trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")
    trial.set_constraint(CONSTRAINT, design.pivot_radius - design.l)
    if not design.can_tumble:
        trial.set_user_attr("infeasible", f"l={design.l:.3f} m < r={design.pivot_radius:.3f} m: the legs "
                                          "cannot lift the body past its balance point")
        study.tell(trial, _imputed_value(study))
        return None, 0
    # Ctrl-C or a crash from here on: optimize() fails the trial and flags it interrupted.
    started = time.perf_counter()
    R, e, per_episode = _evaluate(objective, runner, design, 0, recipe.screen_batch, seed, on_result)
    value = float(np.mean(per_episode))
    trial.set_user_attr("e", e)
    trial.set_user_attr("batch", recipe.screen_batch if objective.tasks else 0)
    trial.set_user_attr("R", R)
    trial.set_user_attr("mean_R", {t: float(np.mean(r)) for t, r in R.items()})
    trial.set_user_attr("seconds", time.perf_counter() - started)
    added = recipe.screen_batch * len(objective.tasks)
    if not math.isfinite(value):
        trial.set_user_attr("infeasible", f"objective is {value} (NaN or infinite result)")
        study.tell(trial, state=TrialState.FAIL)
        return None, added
    study.tell(trial, value)
    return value, added


def _top_is_promoted(study: optuna.Study, objective: Objective, top: int) -> bool:
    """Whether the ``top`` most promising screened designs all have full-batch results."""
    done = promotions(study)
    scores = screen_scores(study, objective)
    ranked = sorted(scores, key=lambda n: scores[n], reverse=True)
    return all(n in done for n in ranked[:top])


def study_summary(study: optuna.Study) -> dict[str, Any]:
    """A JSON-ready summary: the objective, counts and the optimum."""
    from optuna.trial import TrialState

    config = load_config(study)
    if config is None:
        raise OptimizeError(f"study {study.study_name!r} was not made by tumblebot optimize")
    trials = study.get_trials(deepcopy=False)
    best = best_candidate(study)
    return {
        "study": study.study_name,
        "config": asdict(config),
        "trials": counted_trials(study),  #: what the terminal says: finished, infeasible and running ones
        "feasible": sum(t.state == TrialState.COMPLETE and not _is_infeasible(t) for t in trials),
        "infeasible": sum(_is_infeasible(t) for t in trials),
        "interrupted": sum(bool(t.user_attrs.get("interrupted")) for t in trials),
        "episodes": episode_count(study),
        "best": None if best is None else {
            "trial": best.trial, "design": best.design.as_dict(),
            "objective": best.value, "batch": best.batch, "e": best.e,
            "mean_R": {t: float(np.mean(r)) for t, r in best.R.items()},
        },
    }


def episode_count(study: optuna.Study) -> int:
    """Episodes the study has cost so far (screening, full batches and promotions)."""
    total = 0
    for t in study.get_trials(deepcopy=False):
        total += sum(len(r) for r in t.user_attrs.get("R", {}).values())
    for number, p in promotions(study).items():
        screened = study.trials[number].user_attrs.get("R", {})
        total += sum(len(r) for r in p["R"].values()) - sum(len(r) for r in screened.values())
    return total


def to_json(obj: Any) -> str:
    return json.dumps(obj, indent=2, default=lambda o: None if isinstance(o, float) and not math.isfinite(o) else o)
