"""Reading a study: its trials, promotions, full-batch results, the best design, the summary;
sampling, and the controllers a study's episodes are driven by."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tumblebot import jsonio
from tumblebot.sim.evaluation.evaluate import Driver
from tumblebot.sim.optimize.objective import Objective, OptimizeError
from tumblebot.sim.optimize.recipes import Recipe
from tumblebot.sim.optimize.storage import TrialRecord, load_config, promotions
from tumblebot.sim.optimize.surrogate import RSampler
from tumblebot.sim.world.design import PARAMETERS, Design
from tumblebot.sim.world.physics import PhysicsProfile

if TYPE_CHECKING:
    import optuna


# --------------------------------------------------------------------------- sampling
class TrialNumberSampler:
    """Start-up designs drawn from ``SeedSequence([seed, trial.number])``: the same designs
    whichever process runs which trial, so a study is reproducible with any worker count."""

    def __init__(self, seed: int) -> None:
        self.seed = seed

    def value(self, trial_number: int, name: str, low: float, high: float) -> float:
        ss = np.random.SeedSequence([self.seed, trial_number, PARAMETERS.index(name)])
        return float(np.random.default_rng(ss).uniform(low, high))


def make_sampler(recipe: Recipe, seed: int, process_salt: int, objective: Objective | None = None
                 ) -> optuna.samplers.BaseSampler:
    """The study's sampler: seeded random start-up designs, then a GP.

    The efficient recipe and front studies use :class:`~tumblebot.sim.optimize.surrogate.RSampler`
    (a GP on ``R`` alone, each trial's noise its own, ``e(w)`` exact); the other recipes use
    Optuna's ``GPSampler`` on the objective (the thesis's acquisition, GP-EI)."""
    import optuna
    from optuna.distributions import BaseDistribution, FloatDistribution

    base = TrialNumberSampler(seed)

    class _Startup(optuna.samplers.RandomSampler):
        def sample_independent(self, study: optuna.Study, trial: optuna.trial.FrozenTrial, param_name: str,
                               param_distribution: BaseDistribution) -> Any:
            if not isinstance(param_distribution, FloatDistribution):  # every design parameter is a float range
                raise TypeError(f"{param_name}: a {type(param_distribution).__name__}, not a FloatDistribution")
            return base.value(trial.number, param_name, param_distribution.low, param_distribution.high)

    salted = int(np.random.SeedSequence([seed, process_salt]).generate_state(1)[0])
    if objective is not None and recipe.surrogate(objective) == "R":
        return RSampler(objective.weights, objective.targets, recipe.startup, _Startup(seed=seed), salted)
    return optuna.samplers.GPSampler(seed=salted, independent_sampler=_Startup(seed=seed),
                                     n_startup_trials=recipe.startup, deterministic_objective=False,
                                     warn_independent_sampling=False)


# --------------------------------------------------------------------------- trials
def _is_infeasible(t: optuna.trial.FrozenTrial) -> bool:
    return TrialRecord.of(t).infeasible is not None


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


#: The first episode index of own screens, far above any full batch's ``0..B-1``.
OWN_SCREENS_FROM = 1_000_000


def screen_episodes(study: optuna.Study, number: int, recipe: Recipe) -> tuple[int, int]:
    """The episode range ``(start, stop)`` of trial ``number``'s first batch.

    A full batch (``screen = B``) is episodes ``0..B-1`` for every design (common random
    numbers: designs compared on the same episodes). A screen of an efficient study made
    with own screens (:attr:`~tumblebot.sim.optimize.storage.StudyConfig.screens`) runs ``s``
    episodes no other trial runs: a screen's luck is then its own, and the GP, which pools
    hundreds of screens, averages it away. Shared screens (episodes ``0..s-1`` for every
    trial) share their luck too: where those few episodes happen to suit a region's designs,
    every screen there reads high together, and no number of screens averages that out (on
    ``benchmarks/bench_optimize.py``'s seed 1 a single final promotion went to legs of
    0.082 m rated 0.00967 from such screens; 240 episodes gave 0.00901)."""
    s = recipe.screen_batch
    config = load_config(study)
    if s >= recipe.batch or (config is not None and config.screens != "own"):
        return 0, s
    return OWN_SCREENS_FROM + number * s, OWN_SCREENS_FROM + (number + 1) * s


def trial_design(t: optuna.trial.FrozenTrial) -> Design:
    return Design(*(t.params[n] for n in PARAMETERS))


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
        rec = TrialRecord.of(t)
        if rec.infeasible is not None or rec.e is None:
            continue
        if t.number in promoted:
            p = promoted[t.number]
            out.append(Candidate(t.number, trial_design(t), float(p["value"]), int(p["batch"]), p["R"], rec.e))
        elif (rec.batch >= config.batch or rec.batch == 0) and t.value is not None:
            out.append(Candidate(t.number, trial_design(t), float(t.value), rec.batch, rec.R, rec.e))
    return out


def value_at(candidate: Candidate, objective: Objective) -> float:
    """A candidate's batch-mean objective recomputed for ``objective`` (another ``ξ``)."""
    R = {t: np.asarray(r, float) for t, r in candidate.R.items()}
    return float(np.mean(objective.per_episode(R, candidate.e)))


def front_optima(study: optuna.Study, xis: tuple[float, ...]) -> dict[float, Candidate]:
    """A front study's optimum of each ``ξ``: the full-batch design of best objective at that
    ``ξ``; for ``ξ = ∞``, the design of least ``e(w)`` among all evaluated ones whose mean
    ``R`` is positive (``e`` is exact, so a screening batch suffices to show it moves)."""
    from optuna.trial import TrialState

    config = load_config(study)
    if config is None:
        raise OptimizeError(f"study {study.study_name!r} was not made by tumblebot optimize")
    objective = config.objective()
    full = full_batch_results(study)
    out: dict[float, Candidate] = {}
    for xi in xis:
        if math.isinf(xi):
            records = [(t, TrialRecord.of(t)) for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))]
            moving = [Candidate(t.number, trial_design(t), -rec.e, rec.batch, rec.R, rec.e) for t, rec in records
                      if rec.infeasible is None and rec.e is not None and rec.R
                      and all(float(np.mean(r)) > 0 for r in rec.R.values())]
            if moving:
                out[xi] = max(moving, key=lambda c: c.value)
            continue
        at = objective.at(xi)
        scored = [Candidate(c.trial, c.design, value_at(c, at), c.batch, c.R, c.e) for c in full]
        if scored:
            out[xi] = max(scored, key=lambda c: c.value)
    return out


def best_candidate(study: optuna.Study, cands: list[Candidate] | None = None) -> Candidate | None:
    """The study's optimum (None before any design has its full batch).

    Of the designs with a full batch (``cands``, if already read: :func:`full_batch_results`):
    in a study of the efficient recipe (single ``ξ``, the thesis wrapper), the one the GP on
    ``R`` rates best (:func:`posterior_ratings`); in any other, the best full batch."""
    cands = full_batch_results(study) if cands is None else cands
    if not cands:
        return None
    rated = posterior_ratings(study, [c.trial for c in cands])
    if rated:
        return max(cands, key=lambda c: (rated[c.trial], c.value))
    return max(cands, key=lambda c: c.value)


def posterior_ratings(study: optuna.Study, numbers: list[int]) -> dict[int, float]:
    """The posterior-mean objective of trials ``numbers`` under the GP on ``R`` fitted to every
    episode of an efficient-recipe study, or ``{}`` for another study (or before the GP has
    three designs).

    The efficient recipe promotes its most promising designs, which late in a study are
    near-copies of one another; their 48-episode full batches differ by luck about as much
    as by design, and the luckiest would win on its luck. The GP pools each design's
    episodes with its neighbours', so the choice follows the surface, not the luck."""
    from tumblebot.sim.optimize import surrogate

    config = load_config(study)
    if config is None or config.recipe != "efficient" or config.front or config.variant != "thesis" \
            or not config.weights or math.isinf(float(config.xi)):
        return {}
    ratings = surrogate.study_posterior(study, config.weights, float(config.xi))
    if not all(n in ratings for n in numbers):
        return {}
    return {n: ratings[n] for n in numbers}


def study_drivers(controller: str, tasks: list[str], allow_servo_mismatch: bool = False,
                  physics: PhysicsProfile | None = None, policies: dict[str, Path] | None = None
                  ) -> dict[str, Driver]:
    """``controller`` ``"policy"`` (each task's bundled ONNX policy), ``"thesis-policy"``
    (the bundled ones with the thesis observation) or a gait name (``goto`` and ``plan``
    included), as a task → :class:`Driver` map, each checked for its task and ``physics``
    (here, before a study is opened or written). ``policies`` (``--policy TASK=FILE``)
    replaces the bundled policy of its tasks: a study pinned to the files it used."""
    policies = policies or {}
    if policies and controller not in ("policy", "thesis-policy"):
        raise OptimizeError(f"--policy drives episodes with an ONNX policy; the controller here is {controller!r}")
    unknown = sorted(set(policies) - set(tasks))
    if unknown:
        raise OptimizeError(f"--policy for {', '.join(unknown)}: not a task of {', '.join(tasks) or 'the study'}")
    if controller in ("policy", "thesis-policy"):
        rest = [t for t in tasks if t not in policies]
        files = {**bundled_policies(rest, thesis=controller == "thesis-policy"), **policies}
        out = {t: Driver("onnx", str(files[t]), allow_servo_mismatch) for t in tasks}
    else:
        out = {t: Driver.of_gait(controller) for t in tasks}
    for t, c in out.items():
        c.check(t, physics)
    return out


def parse_policy_files(values: list[str] | None, tasks: list[str] | None = None) -> dict[str, Path]:
    """``--policy [TASK=]FILE`` (repeatable) as task → file. A bare FILE is the policy of
    the only task in ``tasks``. Each file must exist; the policy itself is checked when
    its driver is (:meth:`Driver.check`)."""
    from tumblebot.sim.world.tasks import get_task

    out: dict[str, Path] = {}
    for value in values or []:
        task, sep, name = value.rpartition("=")
        if not sep:
            if tasks is None or len(tasks) != 1:
                raise OptimizeError(f"--policy {value}: say which task it drives, as TASK=FILE")
            task = tasks[0]
        task = get_task(task).name
        if task in out:
            raise OptimizeError(f"--policy gives two files for {task}")
        path = Path(name)
        if not path.is_file():
            raise OptimizeError(f"--policy {value}: {path} is not a file")
        out[task] = path
    return out


def bundled_policies(tasks: list[str], thesis: bool = False) -> dict[str, Path]:
    """The bundled ONNX policy of each task (with ``thesis``, the one that sees only the
    thesis observation, :func:`~tumblebot.sim.control.policy.bundled_policy`)."""
    from tumblebot.sim.control.policy import PolicyError, bundled_policy

    out = {t: bundled_policy(t, "thesis" if thesis else None) for t in tasks}
    missing = [t for t, path in out.items() if not path.is_file()]
    if missing:
        raise PolicyError(f"no bundled policy for {', '.join(missing)} yet (policies/TASK.onnx); "
                          "train and export one first (tumblebot train / tumblebot export)")
    return out


def format_best(best: Candidate | None, objective: Objective, so_far: bool = False) -> str:
    """The optimum as a small table, for the terminal (``so_far``: trials are still running)."""
    if best is None:
        return "no design has been evaluated on the full batch yet"
    w = best.design
    lines = [f"best robot{' so far' if so_far else ''}: trial {best.trial}, {best.batch} episodes per task",
             "  x = {:.3f} m   y = {:.3f} m   z = {:.3f} m   l = {:.3f} m".format(*w.as_tuple()),
             f"  e(w) = {best.e:.3f} W/m   objective = {best.value:.5g}"]
    for task, R in best.R.items():
        lines.append(f"  {task}: mean R = {float(np.mean(R)):.3f} (weight {objective.weights[task]:g})")
    lines.append(f"  exact design: tumblebot power {exact_design(best.design)}")
    return "\n".join(lines)


def running_trials(study: optuna.Study) -> list[int]:
    """Trials another worker is still running (a dead worker's are failed by its heartbeat)."""
    from optuna.trial import TrialState

    return [t.number for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))]


def exact_design(design: Design) -> str:
    """The design with the digits that reproduce its e(w): near the legs' limit l = r, e(w)
    changes by whole W/m within a millimetre, so the table's rounded numbers may not."""
    return " ".join(f"{v:.8g}" for v in design.as_tuple())



def format_front(study: optuna.Study) -> str:
    """A front study's optimum of each of its ξ, as a small table, for the terminal."""
    config = load_config(study)
    if config is None:
        raise OptimizeError(f"study {study.study_name!r} was not made by tumblebot optimize")
    objective = config.objective()
    optima = front_optima(study, objective.front)
    lines = ["optimum of each ξ (read from the front):",
             "  ξ     trial  x      y      z      l      e (W/m)  mean R  episodes  objective"]
    for xi in objective.front:
        c = optima.get(xi)
        label = "inf" if math.isinf(xi) else f"{xi:g}"
        if c is None:
            lines.append(f"  {label:<5} none on the full batch yet")
            continue
        R = float(np.mean(np.sum([objective.weights[k] * np.asarray(v) for k, v in c.R.items()], axis=0)))
        lines.append(f"  {label:<5} {c.trial:>5}  {c.design.x:.3f}  {c.design.y:.3f}  {c.design.z:.3f}  "
                     f"{c.design.l:.3f}  {c.e:7.3f}  {R:6.3f}  {len(next(iter(c.R.values()))):>8}  {c.value:.5g}")
    exact = [f"  ξ = {'inf' if math.isinf(xi) else f'{xi:g}'}: tumblebot power {exact_design(optima[xi].design)}"
             for xi in objective.front if optima.get(xi) is not None]
    if exact:
        lines += ["exact designs:", *exact]
    return "\n".join(lines)


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
        "interrupted": sum(TrialRecord.of(t).interrupted for t in trials),
        "episodes": episode_count(study),
        "best": None if best is None else _candidate_json(best),
        **({"front": {("inf" if math.isinf(xi) else f"{xi:g}"): _candidate_json(c)
                      for xi, c in front_optima(study, config.objective().front).items()}}
           if config.front else {}),
    }


def _candidate_json(c: Candidate) -> dict[str, Any]:
    return {"trial": c.trial, "design": c.design.as_dict(), "objective": c.value, "batch": c.batch, "e": c.e,
            "mean_R": {t: float(np.mean(r)) for t, r in c.R.items()}}


def episode_count(study: optuna.Study) -> int:
    """Episodes the study has cost so far (screening, full batches and promotions)."""
    total = 0
    for t in study.get_trials(deepcopy=False):
        total += TrialRecord.of(t).episodes
    for number, p in promotions(study).items():
        total += sum(len(r) for r in p["R"].values()) - TrialRecord.of(study.trials[number]).episodes
    return total


def to_json(obj: Any) -> str:
    """``obj`` as strict JSON (a non-finite number as ``null``; NumPy's numbers as Python's)."""
    return jsonio.dumps(obj)
