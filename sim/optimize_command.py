"""The ``optimize`` command: the study's plan from the arguments, the progress bar, the run."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tumblebot.cliargs import (
    Subcommands,
    add_mismatch_argument,
    add_servo_arguments,
    check_writable,
    seed_type,
)
from tumblebot.errors import TumblebotError
from tumblebot.sim.world.physics import PhysicsProfile, profile_from_args

if TYPE_CHECKING:  # the optimiser (Optuna, SciPy) loads only when a study runs
    from tumblebot.sim.control.drivers import Driver
    from tumblebot.sim.optimize import Objective, Recipe, StudyConfig


@dataclass(frozen=True)
class OptimizePlan:
    """``optimize``'s arguments, checked: what the study runs and where it is stored."""

    objective: Objective
    recipe: Recipe
    physics: PhysicsProfile
    drivers: dict[str, Driver]  #: task → what drives its episodes
    config: StudyConfig  #: what the study stores and checks on resume
    name: str  #: the study's name
    storage_url: str


def _optimize_plan(args: argparse.Namespace) -> OptimizePlan:
    """``optimize``'s arguments checked, before any study is opened or written."""
    import os

    from tumblebot.sim.control.policy import sha256_of
    from tumblebot.sim.optimize import (
        DEFAULT_STORAGE,
        Objective,
        OptimizeError,
        Recipe,
        StudyConfig,
        format_xi,
        parse_policy_files,
        parse_tasks,
        parse_xi,
        parse_xi_list,
        study_drivers,
    )

    if args.front is not None and args.xi is not None:
        raise OptimizeError("give --xi or --front, not both (a front study serves every ξ of its list)")
    if args.front is not None:
        objective = Objective(parse_tasks(args.tasks), 0.0, args.variant, parse_xi_list(args.front))
        if not any(math.isfinite(x) for x in objective.front):
            raise OptimizeError("--front needs a finite ξ (ξ = inf alone costs no episodes: use --xi inf)")
    else:
        objective = Objective(parse_tasks(args.tasks), parse_xi(args.xi or "0"), args.variant)
    batch = args.batch
    if objective.tasks == [] and batch is None and args.recipe != "thesis":
        batch = 1  # ξ = inf: e(w) alone, no episodes, so no batch to choose
    recipe = Recipe.make(args.recipe, args.trials, batch, args.startup)
    if args.workers < 1:
        raise OptimizeError(f"--workers {args.workers} must be at least 1")
    if args.episode_budget is not None and args.episode_budget < 1:
        raise OptimizeError(f"--episode-budget {args.episode_budget} must be at least 1")
    if args.json is not None:
        check_writable(args.json, "--json")
    physics = profile_from_args(args)
    if args.gait is not None and args.thesis_policies:
        raise TumblebotError("give --gait or --thesis-policies, not both")
    controller = args.gait or ("thesis-policy" if args.thesis_policies else "policy")
    drivers = study_drivers(controller, objective.tasks, args.allow_servo_mismatch, physics,
                            parse_policy_files(args.policy, objective.tasks))
    policies = {t: Path(c.name) for t, c in drivers.items() if c.kind == "onnx"}
    config = StudyConfig.of(objective, recipe, args.seed, {t: sha256_of(p) for t, p in policies.items()},
                            controller=controller, physics=physics)
    suffix = "-front" if objective.front else f"-xi{format_xi(objective.xi)}"
    name = args.study or "-".join(f"{t}={w:g}" for t, w in objective.weights.items()) + suffix
    storage_url = args.storage or os.environ.get("TUMBLEBOT_STORAGE") or DEFAULT_STORAGE
    return OptimizePlan(objective, recipe, physics, drivers, config, name, storage_url)


def _optimize_bar(trials: int, quiet: bool) -> tuple[Any, Callable[[Any], None]]:
    """The optimiser's progress bar and the callback that moves it (best design so far)."""
    from tqdm import tqdm

    bar = tqdm(total=trials, unit="trial", desc="optimize", disable=quiet, mininterval=0.5)

    def show(p: Any) -> None:
        bar.n = min(p.done, trials)
        if p.best is not None:
            x, y, z, leg = p.best.design
            bar.set_postfix_str(f"best {p.best.value:.4g} at x={x:.3f} y={y:.3f} z={z:.3f} l={leg:.3f}")
        bar.refresh()

    return bar, show


def _optimize(args: argparse.Namespace) -> int:
    import dataclasses

    from tumblebot.sim.evaluation.runner import EpisodeRunner
    from tumblebot.sim.optimize import (
        StopFlag,
        StopRequested,
        format_best,
        format_front,
        load_config,
        open_storage,
        open_study,
        optimize,
        running_trials,
    )
    from tumblebot.sim.optimize.storage import redact_url

    plan = _optimize_plan(args)
    objective, recipe, name, storage_url = plan.objective, plan.recipe, plan.name, plan.storage_url
    stop = StopFlag()
    with stop.installed():  # from here on Ctrl-C only asks; the work stops at its next safe point
        if stop():  # Ctrl-C while the command was starting up: stop before the study is opened
            print("stopped before the study was opened", file=sys.stderr)
            return 130
        study = open_study(open_storage(storage_url, writable=True), name, plan.config)
        stored = load_config(study)
        if args.startup is None and stored is not None and stored.startup != recipe.startup:
            recipe = dataclasses.replace(recipe, startup=stored.startup)  # keep the study's schedule on resume
        print(f"study {name!r} in {redact_url(storage_url)}: {objective.describe()}, recipe {recipe.name} "
              f"({recipe.trials} trials, {recipe.startup} random then "
              + ("a GP on R with e(w) exact" if recipe.surrogate(objective) == "R" else "GP-logEI")
              + f", batch {recipe.batch}"
              + (f", screening {recipe.screen_batch}" if recipe.screen_batch != recipe.batch else "") + ")",
              file=sys.stderr)
        bar, show = _optimize_bar(recipe.trials, args.quiet)
        runner = None
        try:
            runner = EpisodeRunner(plan.drivers, workers=args.workers, physics=plan.physics) \
                if objective.tasks else None
            result = optimize(study, objective, recipe, runner, args.seed, on_progress=show,
                              episode_budget=args.episode_budget, should_stop=stop)
        except (StopRequested, KeyboardInterrupt):
            bar.close()
            print(f"\nstopped; finished trials are kept in {redact_url(storage_url)}. Run the same command to resume.",
                  file=sys.stderr)
            return 130
        finally:
            if runner is not None:
                runner.close()
        bar.close()
    print(f"{result.done} trials in study {name!r} ({result.episodes} episodes this run)")
    running = running_trials(study)
    if running:
        listed = ", ".join(str(n) for n in running[:10]) + (", …" if len(running) > 10 else "")
        print(f"{len(running)} trial{'s' if len(running) > 1 else ''} still running in other workers ({listed}): "
              "the result below is the best so far, not yet the study's; run the same command (or report) "
              "when they finish")
    print(format_front(study) if objective.front else format_best(result.best, objective, so_far=bool(running)))
    if args.json is not None:
        from tumblebot.sim.optimize import study_summary, to_json

        try:
            args.json.write_text(to_json(study_summary(study)) + "\n")
        except OSError as exc:
            raise TumblebotError(f"--json {args.json}: cannot write: {exc.strerror}") from None
    return 0


def _add_optimize_command(sub: Subcommands) -> None:
    """The ``optimize`` command."""
    p = sub.add_parser(
        "optimize", help="Bayesian optimisation of the design (x, y, z, l) for weighted tasks",
        description="Maximise the thesis objective, the batch mean of sum_i lambda_i R_i/(e(w)+1)^xi, over the "
                    "design bounds with each task's bundled ONNX policy. Every recipe starts with random designs; "
                    "then the standard and thesis recipes use Optuna's GP sampler (log expected improvement) on "
                    "the objective, while the efficient recipe and every --front study fit a GP to R alone with "
                    "e(w) exact, screen designs on a few episodes and promote the promising ones to the full "
                    "batch. Studies live in a database (SQLite file by "
                    "default); running the same command again resumes a study, and several processes pointed at "
                    "one study cooperate on it. Ctrl-C stops cleanly.")
    p.add_argument("--tasks", required=True, help="weighted tasks, e.g. nav-flat=1,incline=0.5 (a bare name weighs 1)")
    p.add_argument("--xi", default=None, help="energy exponent xi >= 0, or inf to minimise e(w) alone (default 0)")
    p.add_argument("--front", nargs="?", const="0,1,3,inf", default=None, metavar="XIS",
                   help="instead of one xi, search the front of high R and low e(w) for every xi in XIS (default "
                        "0,1,3,inf): a GP on R with e(w) exact, its acquisition going where some xi has the most "
                        "to gain; report --xi reads each optimum from it")
    p.add_argument("--trials", type=int, help="designs to evaluate in the study (all workers together)")
    p.add_argument("--batch", type=int, help="episodes per task for a design's full evaluation (thesis: 240)")
    p.add_argument("--startup", type=int, help="random designs before the GP (default: half the trials, at most 20)")
    p.add_argument("--recipe", choices=("standard", "thesis", "efficient"), default="standard",
                   help="standard: every trial gets the full batch; thesis: 1000 random + 1000 EI, batch 240 "
                        "(fixes --trials/--batch/--startup); efficient: screen on batch/15 episodes and promote the "
                        "best designs to the full batch (default standard)")
    p.add_argument("--episode-budget", type=int, help="also stop once the study has spent this many episodes")
    p.add_argument("--storage", help="Optuna storage URL, e.g. sqlite:///study.db or postgresql://user@host/db "
                                     "(default $TUMBLEBOT_STORAGE, else sqlite:///tumblebot-optuna.db)")
    p.add_argument("--study", help="study name (default from the tasks and xi, e.g. nav-flat=1-xi3, or "
                                   "nav-flat=1-front)")
    p.add_argument("--workers", type=int, default=1, help="processes running episodes (default 1)")
    p.add_argument("--seed", type=seed_type, default=0, help="seed of the episodes and start-up designs (default 0)")
    p.add_argument("--variant", choices=("thesis", "monotone"), default="thesis",
                   help="wrapper for R < 0: the thesis's R/(e+1)^xi or the monotone R*(e+1)^xi (default thesis)")
    p.add_argument("--json", type=Path, help="also write the study summary as JSON to this file")
    p.add_argument("--gait", default=None, metavar="goto|plan",
                   help="drive the episodes with goto, plan or plan-short, the hand-written closed-loop navigation "
                        "controllers (navigation tasks), or a scripted gait, instead of each task's bundled policy; "
                        "recorded in the study")
    p.add_argument("--policy", action="append", metavar="[TASK=]FILE",
                   help="drive TASK's episodes with this ONNX policy instead of the bundled one (repeat for several "
                        "tasks; a bare FILE needs a single task). The study records each policy's SHA-256 and "
                        "refuses to resume with another file")
    p.add_argument("--thesis-policies", action="store_true",
                   help="drive the episodes with the bundled policies that see only the thesis's 9-number "
                        "observation (policies/TASK-thesis.onnx where the best one also takes the design), as the "
                        "thesis did; recorded in the study")
    add_servo_arguments(p)
    add_mismatch_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    # Ctrl-C stays latched until optimize's StopFlag takes it over: nothing in its start-up
    # (imports, policy checks) can lose it.
    p.set_defaults(func=_optimize, holds_interrupts=True)


def add_command(sub: Subcommands) -> None:
    """Add ``optimize`` to the ``tumblebot`` parser's subcommands."""
    _add_optimize_command(sub)
