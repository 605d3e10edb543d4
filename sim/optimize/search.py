"""The search loop: ask, evaluate on the episode runner, tell; screening and promotion;
safe points for Ctrl-C; heartbeats."""

from __future__ import annotations

import contextlib
import math
import os
import socket
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tumblebot.sim.evaluation.score import wrap_reward
from tumblebot.sim.optimize.objective import Objective, OptimizeError, StopRequested
from tumblebot.sim.optimize.recipes import Recipe
from tumblebot.sim.optimize.storage import PROMOTED_PREFIX, TrialRecord, _storage_of, promotions
from tumblebot.sim.optimize.trials import (
    CONSTRAINT,
    Candidate,
    _imputed_value,
    _is_infeasible,
    best_candidate,
    counted_trials,
    episode_count,
    full_batch_results,
    make_sampler,
    screen_episodes,
    trial_design,
)
from tumblebot.sim.world.design import BOUNDS, PARAMETERS, Design
from tumblebot.sim.world.power import energy_per_metre

if TYPE_CHECKING:
    import optuna

    from tumblebot.sim.evaluation.runner import EpisodeRunner

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
              if t.value is not None and not _is_infeasible(t) and TrialRecord.of(t).R]
    if not trials:
        return {}
    span = np.array([BOUNDS[n][1] - BOUNDS[n][0] for n in PARAMETERS])
    X = np.array([[t.params[n] for n in PARAMETERS] for t in trials]) / span
    d2 = ((X[:, None, :] - X[None, :, :]) ** 2).sum(-1)
    K = np.exp(-d2 / (2 * SMOOTHING_WIDTH ** 2))
    scores: dict[int, float] = {}
    for task in objective.tasks:
        n = np.array([len(TrialRecord.of(t).R[task]) for t in trials], dtype=float)
        mean = np.array([float(np.mean(TrialRecord.of(t).R[task])) for t in trials])
        smooth = (K * n) @ mean / (K @ n)
        for t, r in zip(trials, smooth, strict=True):
            e = float(TrialRecord.of(t).e)  # type: ignore[arg-type]
            scores[t.number] = scores.get(t.number, 0.0) + objective.weights[task] * wrap_reward(
                float(r), e, objective.xi, objective.variant)
    return scores


def promotion_scores(study: optuna.Study, objective: Objective, xi: float) -> dict[int, float]:
    """Each screened or promoted trial's expected objective at ``ξ``, for choosing promotions.

    With three or more results, the posterior mean of the GP on ``R``
    (:mod:`~tumblebot.sim.optimize.surrogate`: every batch weighted by its own noise, a
    screening batch and a full batch as low- and high-fidelity looks at the same ``R``)
    divided by the exact ``(e+1)^ξ``, for every trial but those whose own episodes put them in
    the study's worst tenth (:func:`~tumblebot.sim.optimize.surrogate.capped`: the GP sees
    them raised, so it could rate one as well as its neighbours); before that, and for the
    monotone wrapper (not linear in ``R``), :func:`screen_scores`."""
    from tumblebot.sim.optimize import surrogate

    posterior = surrogate.study_posterior(study, objective.weights, xi, promotable=True) \
        if objective.variant == "thesis" else {}
    return posterior or screen_scores(study, objective.at(xi))


def _promote(study: optuna.Study, objective: Objective, recipe: Recipe, runner: EpisodeRunner | None,
             seed: int, on_result: Callable[[], object] | None = None, xi: float | None = None) -> int:
    """Extend the most promising not-yet-promoted screened trial at ``ξ`` (by
    :func:`promotion_scores`; default the study's ``ξ``) to the full batch. Returns episodes run."""
    done = promotions(study)
    pending = {int(k[len("promoting:"):]) for k, v in study.user_attrs.items() if k.startswith("promoting:") and v}
    ranked = promotion_scores(study, objective, objective.xi if xi is None else xi)
    scores = {n: v for n, v in ranked.items() if n not in done and n not in pending}
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
    R = {task: list(TrialRecord.of(t).R[task]) + more[task] for task in objective.tasks}
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
    sampler = make_sampler(recipe, seed, process_salt=len(study.trials), objective=objective)
    study.sampler = sampler
    distributions: dict[str, optuna.distributions.BaseDistribution] = {
        n: optuna.distributions.FloatDistribution(*BOUNDS[n]) for n in PARAMETERS}
    episodes = 0
    last_value: float | None = None
    last_state = ""
    n_tasks = len(objective.tasks)
    spent_before = episode_count(study) if episode_budget is not None else 0
    targets = objective.targets
    reserve = recipe.final_promotions * len(targets) * (recipe.batch - recipe.screen_batch) * n_tasks
    if objective.front:
        _enqueue_least_energy(study, seed)

    def affordable(cost: int, keep: int = 0) -> bool:
        return episode_budget is None or spent_before + episodes + cost + keep <= episode_budget

    best = _BestSoFar(study)

    def progress() -> Progress:
        p = Progress(counted_trials(study), recipe.trials, episodes, best(), last_value, last_state)
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
            xi = targets[len(promotions(study)) % len(targets)]  # a front study serves its ξ in turn
            episodes += _promote(study, objective, recipe, runner, seed, safe_point, xi)
        progress()
    if objective.tasks and recipe.screen_batch < recipe.batch:
        episodes += _final_promotions(study, objective, recipe, runner, seed, safe_point,
                                      lambda: affordable(promotion))
    return progress()


#: Study attribute: how many trials the study held when its final promotions were done. A
#: finished study run again does not promote again (each promotion moves the GP, so the
#: designs it ranks on top can change and the optimum with them); one given more trials does.
FINAL_PROMOTIONS_AT = "final_promotions_at"


class _BestSoFar:
    """:func:`best_candidate` for the progress line, chosen again only when the designs with
    a full batch change (the choice fits the GP, which is too slow to do after every trial)."""

    def __init__(self, study: optuna.Study) -> None:
        self.study = study
        self.key: frozenset[int] | None = None
        self.best: Candidate | None = None

    def __call__(self) -> Candidate | None:
        cands = full_batch_results(self.study)
        key = frozenset(c.trial for c in cands)
        if key != self.key:
            self.key, self.best = key, best_candidate(self.study, cands)
        return self.best


def _final_promotions(study: optuna.Study, objective: Objective, recipe: Recipe, runner: EpisodeRunner | None,
                      seed: int, safe_point: Callable[[], None], affordable: Callable[[], bool]) -> int:
    """At the end, for each target ξ: promote until its ``final_promotions`` most promising
    designs have their full batch (or the budget is spent), once for a given number of
    trials (:data:`FINAL_PROMOTIONS_AT`). Returns episodes run."""
    episodes = 0
    if study.user_attrs.get(FINAL_PROMOTIONS_AT) == counted_trials(study):
        return 0
    for xi in objective.targets:
        for _ in range(recipe.final_promotions):
            safe_point()
            if _top_is_promoted(study, objective, recipe.final_promotions, xi) or not affordable():
                break
            episodes += _promote(study, objective, recipe, runner, seed, safe_point, xi)
    study.set_user_attr(FINAL_PROMOTIONS_AT, counted_trials(study))
    return episodes


def _enqueue_least_energy(study: optuna.Study, seed: int) -> None:
    """A front study's first trial: the feasible design of least ``e(w)`` (found without
    episodes), the low-energy end of the front and the ``ξ = ∞`` answer. Enqueued unless a
    trial of that design is finished, running or waiting (so a run stopped during that
    trial enqueues it again on resume)."""
    from optuna.trial import TrialState

    from tumblebot.sim.optimize.surrogate import minimum_energy_design

    w = minimum_energy_design(np.random.default_rng(np.random.SeedSequence([seed, 7919])))
    params = dict(zip(PARAMETERS, (float(v) for v in w), strict=True))
    for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.RUNNING,
                                                        TrialState.WAITING)):
        fixed = t.params or t.system_attrs.get("fixed_params", {})
        if all(math.isclose(float(fixed.get(n, math.nan)), params[n]) for n in PARAMETERS):
            return
    study.enqueue_trial(params)


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


def _mark_interrupted(study: optuna.Study, trial: optuna.Trial) -> None:
    """A trial this process left unfinished (Ctrl-C, a crash): failed and flagged, so it is
    redone, unless it was already told."""
    from optuna.trial import TrialState

    with contextlib.suppress(Exception):
        frozen = [t for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))
                  if t.number == trial.number]
        if frozen:
            TrialRecord.write(trial, interrupted=True)
            study.tell(trial, state=TrialState.FAIL)


def _run_trial(study: optuna.Study, trial: optuna.Trial, objective: Objective, recipe: Recipe,
               runner: EpisodeRunner | None, seed: int, on_result: Callable[[], object] | None = None
               ) -> tuple[float | None, int]:
    """Evaluate one asked trial and tell its result. Returns (value or None, episodes run)."""
    from optuna.trial import TrialState

    design = Design(*(trial.params[n] for n in PARAMETERS))
    TrialRecord.write(trial, worker=f"{socket.gethostname()}:{os.getpid()}")
    trial.set_constraint(CONSTRAINT, design.pivot_radius - design.l)
    if not design.can_tumble:
        TrialRecord.write(trial, infeasible=f"l={design.l:.3f} m < r={design.pivot_radius:.3f} m: the legs "
                                            "cannot lift the body past its balance point")
        study.tell(trial, _imputed_value(study))
        return None, 0
    # Ctrl-C or a crash from here on: optimize() fails the trial and flags it interrupted.
    started = time.perf_counter()
    start, stop = screen_episodes(study, trial.number, recipe)
    R, e, per_episode = _evaluate(objective, runner, design, start, stop, seed, on_result)
    value = float(np.mean(per_episode))
    TrialRecord.write(trial, e=e, batch=recipe.screen_batch if objective.tasks else 0, R=R,
                      mean_R={t: float(np.mean(r)) for t, r in R.items()}, seconds=time.perf_counter() - started)
    added = recipe.screen_batch * len(objective.tasks)
    if not math.isfinite(value):
        TrialRecord.write(trial, infeasible=f"objective is {value} (NaN or infinite result)")
        study.tell(trial, state=TrialState.FAIL)
        return None, added
    study.tell(trial, value)
    return value, added


def _top_is_promoted(study: optuna.Study, objective: Objective, top: int, xi: float) -> bool:
    """Whether the ``top`` most promising screened designs at ``ξ`` all have full-batch results."""
    done = promotions(study)
    scores = promotion_scores(study, objective, xi)
    ranked = sorted(scores, key=lambda n: scores[n], reverse=True)
    return all(n in done for n in ranked[:top])
