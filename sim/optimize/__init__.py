"""Design optimisation (thesis §2.6): Bayesian optimisation of ``w = (x, y, z, l)``.

The objective of a design is the thesis's: the mean over a batch of ``B`` episodes of
``Σ_i λ_i·f_i`` with ``f = R / (e(w) + 1)^ξ`` (:mod:`tumblebot.sim.evaluation.score`), each task's
``R`` coming from its bundled ONNX policy. Optuna runs the search: designs drawn at random
for the start-up trials, then its Gaussian-process sampler with log expected improvement
(``qLogEI`` over the designs other workers are still evaluating). Studies live in any
Optuna RDB storage: an SQLite file by default, PostgreSQL or MySQL to share a study
between machines. Every process pointed at the same study cooperates on it.

Noise. ``R`` is random (starts, masses, friction, motor noise, latency), so a design's
objective is a batch mean with a standard error. Three things keep that noise from
steering the search:

* common random numbers: episode ``i`` is the same episode for every design
  (:mod:`tumblebot.sim.evaluation.runner`), so differences between designs are not drowned by
  differences between episodes;
* the GP fits a noise variance (``deterministic_objective=False``) rather than
  interpolating the observations;
* the reported optimum is a design evaluated on the *full* batch (of the efficient
  recipe's, the one its GP rates best; otherwise the best full batch), and the report
  re-evaluates it on fresh episodes, so a lucky batch does not crown it;
* the efficient recipe's GP corrects each screen by the screening bias that the promoted
  designs near it measured (:func:`~tumblebot.sim.optimize.surrogate.screening_bias`):
  common random numbers make every screen in a region share its luck.

Recipes (:class:`Recipe`): ``standard`` (every trial a full batch), ``thesis`` (exactly
the thesis's schedule: 1000 random designs, 1000 EI iterations, ``B = 240``) and
``efficient`` (trials screened on a small batch; the most promising designs are promoted
to the full batch, reusing their screening episodes). The efficient recipe, and every
front study, replace Optuna's GP on the objective by a GP on ``R`` alone with ``e(w)``
exact (:mod:`~tumblebot.sim.optimize.surrogate`), which also chooses the promotions; it
sees the log of the leg margin ``l - r`` instead of ``l``, so the cliff where the legs
become too short to tumble is in one place for every body.

Front studies (``Objective.front``): one study for several ``ξ`` at once. Its acquisition
serves every finite ``ξ`` from the same GP on ``R`` (each proposal goes where some ξ has
the most to gain), and :func:`front_optima` reads the optimum of each ``ξ`` from its
full-batch designs.

Infeasible designs. Legs shorter than the pivot radius (``l < r``) cannot lift the body
past its balance point. Such trials cost no episodes; they are recorded with the
reason in their :class:`TrialRecord` (``infeasible``), told to Optuna with the worst feasible value so far,
and carry the constraint ``r - l <= 0`` so the GP sampler learns where the boundary is (a
failed trial would be invisible to it, and it would propose the same corner again). They
are never reported as an optimum. A NaN result is recorded as a failed, flagged trial.

Modules: :mod:`~tumblebot.sim.optimize.objective` (what is optimised, the errors, the stop
flag), :mod:`~tumblebot.sim.optimize.recipes`, :mod:`~tumblebot.sim.optimize.storage`
(study storage, what a study was made for), :mod:`~tumblebot.sim.optimize.trials` (reading
a study), :mod:`~tumblebot.sim.optimize.search` (the loop). Everything public is importable
from this package, as it was from the single module it replaces.
"""

from __future__ import annotations

from tumblebot.sim.optimize import surrogate
from tumblebot.sim.optimize.objective import (
    Objective,
    OptimizeError,
    StopFlag,
    StopRequested,
    format_xi,
    parse_tasks,
    parse_xi,
    parse_xi_list,
)
from tumblebot.sim.optimize.recipes import (
    Recipe,
)
from tumblebot.sim.optimize.search import (
    HEARTBEAT_EVERY,
    SMOOTHING_WIDTH,
    Progress,
    optimize,
    promotion_scores,
    screen_scores,
)
from tumblebot.sim.optimize.storage import (
    DEFAULT_STORAGE,
    PROMOTED_PREFIX,
    STUDY_KEY,
    StudyConfig,
    TrialRecord,
    load_config,
    load_study,
    open_storage,
    open_study,
    promotions,
)
from tumblebot.sim.optimize.trials import (
    CONSTRAINT,
    Candidate,
    TrialNumberSampler,
    best_candidate,
    bundled_policies,
    counted_trials,
    episode_count,
    format_best,
    format_front,
    front_optima,
    full_batch_results,
    make_sampler,
    parse_policy_files,
    posterior_ratings,
    running_trials,
    study_drivers,
    study_summary,
    to_json,
    trial_design,
    value_at,
)

__all__ = [
    "CONSTRAINT",
    "DEFAULT_STORAGE",
    "HEARTBEAT_EVERY",
    "PROMOTED_PREFIX",
    "SMOOTHING_WIDTH",
    "STUDY_KEY",
    "Candidate",
    "Objective",
    "OptimizeError",
    "Progress",
    "Recipe",
    "StopFlag",
    "StopRequested",
    "StudyConfig",
    "TrialNumberSampler",
    "TrialRecord",
    "best_candidate",
    "bundled_policies",
    "counted_trials",
    "episode_count",
    "format_best",
    "format_front",
    "format_xi",
    "front_optima",
    "full_batch_results",
    "load_config",
    "load_study",
    "make_sampler",
    "open_storage",
    "open_study",
    "optimize",
    "parse_policy_files",
    "parse_tasks",
    "parse_xi",
    "parse_xi_list",
    "posterior_ratings",
    "promotion_scores",
    "promotions",
    "running_trials",
    "screen_scores",
    "study_drivers",
    "study_summary",
    "surrogate",
    "to_json",
    "trial_design",
    "value_at",
]
