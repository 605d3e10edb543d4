"""The ``tumblebot`` command: a thin argument layer over plain functions.

Each subcommand parses its arguments, calls library code, and prints. Any
:class:`~tumblebot.errors.TumblebotError` becomes one ``tumblebot: error: …`` line and
exit status 2, never a traceback. Heavy imports (PyBullet) happen inside the handlers,
so ``tumblebot --help`` and ``tumblebot power`` stay fast.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeAlias

from tumblebot import interrupts
from tumblebot.defaults import MAX_STALL_TORQUE, OBSERVATION_LAYOUTS, XI3_ROBOT_TEXT
from tumblebot.errors import TumblebotError
from tumblebot.paths import check_writable, check_writable_folder

#: The tasks, for help texts (tumblebot.sim.tasks.TASKS is the source, and a test keeps the two
#: equal; importing tumblebot.sim here would pull gymnasium and numpy into building the parser).
TASK_NAMES: tuple[str, ...] = ("nav-flat", "nav-terrain", "distance-flat", "incline")
TASK_CHOICES = ", ".join(TASK_NAMES[:-1]) + " or " + TASK_NAMES[-1]
Subcommands: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"  #: what build_parser's helpers add to


def _power(args: argparse.Namespace) -> int:
    from tumblebot.sim.design import Design
    from tumblebot.sim.mass import DEFAULT_MASS_MODEL
    from tumblebot.sim.power import power_breakdown

    w = Design(args.x, args.y, args.z, args.l, allow_out_of_bounds=args.allow_out_of_bounds)
    b = power_breakdown(w)
    if args.json:
        out = b.as_dict()
        out["mass_breakdown"] = DEFAULT_MASS_MODEL.breakdown(w)
        print(json.dumps(out, indent=None))
        return 0
    print(f"design     {w}")
    print(f"mass       {b.mass:.4f} kg")
    for part, m in DEFAULT_MASS_MODEL.breakdown(w).items():
        print(f"  {part:<14} {m:.4f} kg")
    print(f"r          {w.pivot_radius:.4f} m (pivot corner to leg axis)")
    print(f"d          {b.displacement:.4f} m per 180° tumble")
    if not b.can_tumble:
        print(f"e          cannot tumble: leg l={w.l:.3f} m is not longer than r={w.pivot_radius:.3f} m "
              "(e = inf)")
        return 0
    print(f"flat half  {b.flat_term:.4f} W·rad (from lying flat, φ = atan2(z, y))")
    print(f"tall half  {b.tall_term:.4f} W·rad (from standing tall, φ = atan2(y, z))")
    print(f"e          {b.e:.3f} W/m")
    return 0


def _urdf(args: argparse.Namespace) -> int:
    from tumblebot.sim.design import Design
    from tumblebot.sim.robot import RobotModel, to_urdf

    w = Design.parse(args.design, allow_out_of_bounds=args.allow_out_of_bounds)
    if args.output is not None and str(args.output) != "-":
        _check_writable(args.output, "-o")
    text = to_urdf(RobotModel.from_design(w))
    if args.output is None or str(args.output) == "-":
        sys.stdout.write(text)
    else:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text)
        print(f"wrote {args.output} ({w})", file=sys.stderr)
    return 0


def _sim(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from tumblebot.sim.design import Design
    from tumblebot.sim.episode import run_gait_episode, write_animation
    from tumblebot.sim.randomization import Randomization
    from tumblebot.sim.tasks import get_task

    task = get_task(args.task)  # run_gait_episode checks the gait (or goto) for the task
    w = Design.parse(args.design, allow_out_of_bounds=args.allow_out_of_bounds)
    servo = _servo(args)
    if args.video is not None:
        if args.video.suffix.lower() not in (".gif", ".png"):
            raise TumblebotError(f"--video {args.video}: the file must end in .gif (or .png)")
        _check_writable(args.video, "--video")
    # randomised: the profile's spreads; else nominal everything, on the profile's floor
    rnd = (servo.randomization(Randomization(design=False)) if args.randomize
           else replace(Randomization.off(), friction=servo.friction))
    result = run_gait_episode(task.name, w, args.gait, args.seed, rnd, record=args.video is not None, physics=servo)
    print(f"{task.name}: {task.description}")
    print(f"{w}, gait {args.gait!r}, {servo.describe()}, seed {args.seed}")
    print(f"{'step':>4}  {'action (R, L)':<18} {'x':>7} {'y':>7} {'z':>6}  {'R':>7}")
    labels = ("reverse", "stop", "forward")
    for s in result.steps:
        act = f"{labels[s.action[0]]}/{labels[s.action[1]]}"
        x, y, z = s.position
        print(f"{s.step:>4}  {act:<18} {x:>7.3f} {y:>7.3f} {z:>6.3f}  {s.R:>7.3f}")
    print(f"final-state R = {result.final_R:.3f}  ({result.wall_seconds:.2f} s wall for 20 s simulated)")
    if args.video is not None:
        write_animation(result.frames, args.video)
        print(f"wrote {args.video} ({len(result.frames)} frames)")
    return 0


def _demo(args: argparse.Namespace) -> int:
    from tumblebot.sim.demo import run_demo

    if args.video_dir is not None:
        if args.video_dir.exists() and not args.video_dir.is_dir():
            raise TumblebotError(f"--video-dir {args.video_dir} exists and is not a folder")
        _check_writable(args.video_dir / "nav-flat.gif", "--video-dir")
    run_demo(sys.stdout, video_dir=args.video_dir)
    return 0


def _train(args: argparse.Namespace) -> int:
    from tumblebot.training.ppo import TrainingInterrupted

    try:
        return _train_run(args)
    except TrainingInterrupted as stopped:
        print(f"\n{stopped}", file=sys.stderr)
        return 130


def _train_run(args: argparse.Namespace) -> int:
    from tumblebot.sim.tasks import get_task

    run_dir: Path | None = args.run_dir
    if args.resume:
        return _train_resume(args)
    task = get_task(args.task or "nav-flat")
    if args.init_from is not None and not args.init_from.is_file():
        raise TumblebotError(f"--init-from: {args.init_from} does not exist")
    if run_dir is not None:
        check_writable_folder(run_dir, "--run-dir")
    from tumblebot.training.config import TrainConfig
    from tumblebot.training.ppo import train

    overrides = {k: v for k, v in (("total_steps", args.steps), ("n_envs", args.envs), ("seed", args.seed),
                                   ("checkpoint_every", args.checkpoint_every), ("observation", args.observation),
                                   ("init_from", None if args.init_from is None else str(args.init_from)))
                 if v is not None}
    if any(v is not None for v in (args.physics, args.motor_model, args.stall_torque)):
        overrides.update(_servo(args).as_fields())
    base: dict[str, Any] = {}
    if args.config is not None:  # only the keys the file sets, so a warm start's inherited ones stay
        loaded = TrainConfig.load(args.config).__dict__
        base = {k: loaded[k] for k in json.loads(args.config.read_text())}
    config = TrainConfig.from_dict({**_inherited(args.init_from), **base, "task": task.name, **overrides})
    if run_dir is None:
        import time

        run_dir = Path("runs") / f"{task.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    print(f"training {task.name} for {config.total_steps} steps with {config.envs} environments in {run_dir}")
    final = train(config, run_dir)
    print(f"finished: {final}; learning curve {run_dir / 'learning_curve.png'}")
    return 0


#: options that describe a new run: a resumed run keeps its own (RUN/config.json)
_NEW_RUN_OPTIONS = ("envs", "seed", "checkpoint_every", "config", "physics", "motor_model", "stall_torque",
                    "init_from", "observation")


def _train_resume(args: argparse.Namespace) -> int:
    """``train --resume``: continue a run, refusing the options of a new one."""
    run_dir: Path | None = args.run_dir
    if run_dir is None:
        raise TumblebotError("--resume needs --run-dir RUN (the folder of the run to continue)")
    given = [f"--{name.replace('_', '-')}" for name in _NEW_RUN_OPTIONS if getattr(args, name) is not None]
    if given:
        raise TumblebotError(f"{', '.join(given)}: options of a new run; a resumed run keeps its own settings "
                             f"({run_dir / 'config.json'}); only --steps may extend it")
    config_path = run_dir / "config.json"
    if not config_path.is_file() or not (run_dir / "latest.zip").is_file():
        raise TumblebotError(f"cannot resume: {run_dir} holds no run (config.json and latest.zip)")
    try:
        run_task = json.loads(config_path.read_text()).get("task")
    except (OSError, json.JSONDecodeError, AttributeError) as exc:
        raise TumblebotError(f"cannot resume: {config_path} is not a training config ({exc})") from None
    if args.task is not None and args.task != run_task:
        raise TumblebotError(f"--task {args.task}: {run_dir} is a {run_task} run; resuming cannot change its task")
    check_writable_folder(run_dir, "--run-dir")
    from tumblebot.training.ppo import train

    final = train(None, run_dir, resume=True, total_steps=args.steps)
    print(f"resumed and finished: {final}")
    return 0


def _inherited(init_from: Path | None) -> dict[str, Any]:
    """What a warm start takes from the run it starts from, unless told otherwise: the
    network's input layout and size, and the servo (they must match for the weights to)."""
    if init_from is None:
        return {}
    from tumblebot.training.config import TrainConfig
    from tumblebot.training.export import run_folder

    folder = run_folder(init_from)
    if folder is None:
        return {}
    source = TrainConfig.load(folder / "config.json")
    return {"observation": source.observation, "net_arch": source.net_arch, "motor_model": source.motor_model,
            "stall_torque": source.stall_torque, "physics": source.physics,
            "tumbling_designs_only": source.tumbling_designs_only}


def _imitate(args: argparse.Namespace) -> int:
    from tumblebot.sim.goto import check_navigation_task
    from tumblebot.training.ppo import TrainingInterrupted

    if args.refine is not None:
        return _refine(args)

    task = check_navigation_task(args.task)
    from tumblebot.training.config import TrainConfig
    from tumblebot.training.imitation import ImitationConfig, imitate

    settings = ImitationConfig(iterations=args.iterations, episodes=args.episodes, updates=args.updates)
    config = TrainConfig(task=task, observation=args.observation, tumbling_designs_only=True, net_arch=args.net_arch,
                         n_envs=args.envs if args.envs is not None else 0, seed=args.seed,
                         **_servo(args).as_fields())
    print(f"imitating goto on {task}: {settings.iterations} DAgger iterations of {settings.episodes} episodes, "
          f"{config.envs} environments, in {args.run_dir}")
    try:
        final = imitate(config, settings, args.run_dir,
                        on_iteration=lambda summary: print(summary.describe(), flush=True), choice=args.choice)
    except TrainingInterrupted as stopped:
        print(f"\nstopped at {stopped.steps} steps; {args.run_dir} holds the last finished iteration "
              "(imitation does not resume: start a new run folder)", file=sys.stderr)
        return 130
    print(f"finished: {final}; fine-tune it with: tumblebot train --task {task} --init-from {final}")
    return 0


def _refine(args: argparse.Namespace) -> int:
    from tumblebot.training.imitation import ImitationConfig, refine
    from tumblebot.training.ppo import TrainingInterrupted

    settings = ImitationConfig(iterations=args.iterations, episodes=args.episodes, updates=args.updates)
    workers = args.envs if args.envs is not None else (os.cpu_count() or 1)
    future = f"the mean of {args.draws} futures drawn anew" if args.draws else "the episode's own future"
    print(f"refining {args.refine} toward goto with a {args.lookahead}-step lookahead over {future} "
          f"(target: {args.search_target}): "
          f"{settings.iterations} iterations of {settings.episodes} episodes, {workers} workers, in {args.run_dir}")
    try:
        final = refine(args.refine, args.run_dir, settings, args.lookahead, workers,
                       on_iteration=lambda summary: print(summary.describe(), flush=True), draws=args.draws,
                       target=args.search_target)
    except TrainingInterrupted as stopped:
        print(f"\nstopped at {stopped.steps} steps; {args.run_dir} holds the last finished iteration",
              file=sys.stderr)
        return 130
    print(f"finished: {final}")
    return 0


def _net_arch(text: str) -> list[int]:
    try:
        sizes = [int(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of layer sizes") from None
    if not sizes or any(n < 1 or n > 4096 for n in sizes):
        raise argparse.ArgumentTypeError(f"{text!r}: layer sizes must be 1–4096")
    return sizes


def _curve(args: argparse.Namespace) -> int:
    from tumblebot.training.curves import CurveError, plot_lineages

    _check_writable(args.output, "-o")
    try:
        chains = plot_lineages(args.runs, args.output)
    except (CurveError, OSError, ValueError, KeyError) as exc:
        raise TumblebotError(f"curve: {exc}") from None
    for run, chain in zip(args.runs, chains, strict=True):
        print(f"{run}: {' -> '.join(chain)}")
    print(f"wrote {args.output}")
    return 0


def _lineage_record(run: Path, steps: int) -> list[dict[str, Any]]:
    """The runs a checkpoint's weights went through, oldest first: each one's folder, the
    steps taken in it and its training wall time up to there (for the model card)."""
    from tumblebot.training.curves import CurveError, lineage
    from tumblebot.training.export import run_folder, wall_seconds_at

    folder = run_folder(run)
    if folder is None:
        return []
    try:
        chain = lineage(folder)
    except CurveError:
        return []
    out = []
    for k, (path, keep, _) in enumerate(chain):
        used = steps if k == len(chain) - 1 else keep
        out.append({"run": path.name, "steps": used, "wall_seconds": wall_seconds_at(path, used)})
    return out


def _export(args: argparse.Namespace) -> int:
    from tumblebot.sim.tasks import get_task, same_goal
    from tumblebot.training.export import export_onnx, load_run, wall_seconds_at, write_card

    if args.output.suffix != ".onnx":
        raise TumblebotError(f"-o {args.output}: the output must end in .onnx")
    previous = None
    if args.baselines_from is not None:  # read before anything is written (it may be the card being replaced)
        try:
            previous = json.loads(args.baselines_from.read_text()).get("evaluation")
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError) as exc:
            raise TumblebotError(f"--baselines-from {args.baselines_from}: not a readable model card ({exc})") from None
    _check_writable(args.output, "-o")
    _check_writable(args.output.with_suffix(".json"), "-o")
    model, config, checkpoint = load_run(args.run)
    if not args.task and config is None:
        raise TumblebotError(f"cannot tell the task of {checkpoint}: no config.json in its run folder; "
                             "pass --task")
    if args.task and config is not None and not same_goal(config.task, get_task(args.task).name):
        raise TumblebotError(f"--task {args.task}: {args.run} was trained for {config.task}, whose reward is "
                             f"another; export it for {config.task} (a navigation run may serve both nav tasks)")
    task = get_task(args.task or (config.task if config else ""))
    export_onnx(model, args.output)
    extra: dict[str, object] = {"checkpoint": str(checkpoint)}
    wall = wall_seconds_at(args.run, int(model.num_timesteps))
    if wall is not None:
        extra["training_wall_seconds"] = wall
    chain = _lineage_record(args.run, int(model.num_timesteps))
    if chain:
        extra["lineage"] = chain
        extra["lineage_wall_seconds"] = sum(r["wall_seconds"] or 0.0 for r in chain)
    if args.note:
        extra["notes"] = args.note
    write_card(args.output, task.name, int(model.num_timesteps), config, extra)
    print(f"wrote {args.output} and {args.output.with_suffix('.json')} ({model.num_timesteps} training steps)")
    if args.eval_episodes > 0:
        from tumblebot.sim.policy import card_path
        from tumblebot.training.card_eval import card_evaluation

        evaluation = card_evaluation(args.output, task.name, args.eval_episodes, args.seed, args.workers, previous)
        card = json.loads(card_path(args.output).read_text())
        card["evaluation"] = evaluation
        card_path(args.output).write_text(json.dumps(card, indent=2) + "\n")
        for label, entry in evaluation["designs"].items():
            lo, hi = entry["ci95"]
            print(f"{label}: mean R {entry['mean_R']:.3f} [{lo:.3f}, {hi:.3f}], best fixed gait "
                  f"{entry['best_fixed_gait']} {entry['baselines'][entry['best_fixed_gait']]['mean_R']:.3f} "
                  f"(p = {entry['p_vs_best_fixed_gait']:.2g}), random {entry['baselines']['random']['mean_R']:.3f}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    import json

    from tumblebot.sim.design import Design
    from tumblebot.sim.evaluate import Controller, evaluate
    from tumblebot.sim.policy import PolicyError, bundled_policy
    from tumblebot.sim.tasks import get_task

    task = get_task(args.task)
    w = Design.parse(args.design, allow_out_of_bounds=args.allow_out_of_bounds)
    if args.episodes < 1 or args.workers < 1:
        raise TumblebotError("--episodes and --workers must be at least 1")
    if args.gait is not None and args.policy is not None:
        raise TumblebotError("give --policy or --gait, not both")
    if args.xi is not None and not args.xi >= 0:
        raise TumblebotError(f"--xi {args.xi} must be >= 0 (or inf)")
    servo = _servo(args)
    if args.gait is not None:
        controller = Controller.of_gait(args.gait)
    else:
        path = args.policy or bundled_policy(task.name)
        if args.policy is None and not path.is_file():
            raise PolicyError(f"no bundled policy for {task.name} ({path.name}); pass --policy FILE")
        controller = Controller("onnx", str(path), allow_servo_mismatch=args.allow_servo_mismatch)
    if args.csv is not None:
        _check_writable(args.csv, "--csv")
    result = evaluate(task.name, w, controller, args.episodes, args.seed, args.workers, progress=not args.json,
                      servo=servo)
    summary = result.summary(xi=args.xi)
    if args.csv is not None:
        import csv

        with args.csv.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(["episode", "final_R", "final_x", "final_y", "final_z", "final_distance"])
            for i, (r, p, d) in enumerate(zip(result.R, result.final_position, result.final_distance, strict=True)):
                writer.writerow([i, f"{r:.6f}", f"{p[0]:.5f}", f"{p[1]:.5f}", f"{p[2]:.5f}", f"{d:.5f}"])
    if args.json:
        print(json.dumps(summary))
        return 0
    lo, hi = summary["ci95"]
    print(f"{task.name}, {w}, {result.controller}, {servo.describe()}, {result.episodes} episodes, seed {args.seed}")
    interval = f"95 % CI {lo:.3f} … {hi:.3f}, sd {summary['sd_R']:.3f}" if result.episodes > 1 else \
        "no CI from one episode"
    print(f"mean final-state R  {summary['mean_R']:.3f}  ({interval})")
    where = "to the goal (the origin)" if task.start == "ring" else "from the start (the origin)"
    print(f"median final distance {where}  {summary['median_final_distance']:.3f} m")
    e = summary["e"]
    print(f"e(w)  {e:.3f} W/m" if e is not None else "e(w)  inf (the design cannot tumble)")
    if "mean_f" in summary and summary["mean_f"] is not None:
        print(f"f = R/(e+1)^ξ with ξ = {args.xi}:  {summary['mean_f']:.5g}")
    if args.csv is not None:
        print(f"per-episode results in {args.csv}")
    return 0


def _optimize_plan(args: argparse.Namespace) -> tuple[Any, Any, Any, dict[str, Any], Any, str, str]:
    """``optimize``'s arguments checked, before any study is opened or written: the
    objective, recipe, servo, controllers, study config, study name and storage URL."""
    import os

    from tumblebot.sim.optimize import (
        DEFAULT_STORAGE,
        Objective,
        OptimizeError,
        Recipe,
        StudyConfig,
        format_xi,
        parse_tasks,
        parse_xi,
        parse_xi_list,
        study_controllers,
    )
    from tumblebot.sim.policy import sha256_of

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
        _check_writable(args.json, "--json")
    servo = _servo(args)
    if args.gait is not None and args.thesis_policies:
        raise TumblebotError("give --gait or --thesis-policies, not both")
    controller = args.gait or ("thesis-policy" if args.thesis_policies else "policy")
    controllers = study_controllers(controller, objective.tasks, args.allow_servo_mismatch, servo)
    policies = {t: Path(c.name) for t, c in controllers.items() if c.kind == "onnx"}
    config = StudyConfig.of(objective, recipe, args.seed, {t: sha256_of(p) for t, p in policies.items()},
                            controller=controller, servo=servo)
    suffix = "-front" if objective.front else f"-xi{format_xi(objective.xi)}"
    name = args.study or "-".join(f"{t}={w:g}" for t, w in objective.weights.items()) + suffix
    storage_url = args.storage or os.environ.get("TUMBLEBOT_STORAGE") or DEFAULT_STORAGE
    return objective, recipe, servo, controllers, config, name, storage_url


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
    from tumblebot.sim.runner import EpisodeRunner

    objective, recipe, servo, controllers, config, name, storage_url = _optimize_plan(args)
    stop = StopFlag()
    with stop.installed():  # from here on Ctrl-C only asks; the work stops at its next safe point
        if stop():  # Ctrl-C while the command was starting up: stop before the study is opened
            print("stopped before the study was opened", file=sys.stderr)
            return 130
        study = open_study(open_storage(storage_url, writable=True), name, config)
        stored = load_config(study)
        if args.startup is None and stored is not None and stored.startup != recipe.startup:
            recipe = dataclasses.replace(recipe, startup=stored.startup)  # keep the study's schedule on resume
        print(f"study {name!r} in {redact_url(storage_url)}: {objective.describe()}, recipe {recipe.name} "
              f"({recipe.trials} trials, {recipe.startup} random then "
              + ("a GP on R with e(w) exact" if recipe.name == "efficient" or objective.front else "GP-logEI")
              + f", batch {recipe.batch}"
              + (f", screening {recipe.screen_batch}" if recipe.screen_batch != recipe.batch else "") + ")",
              file=sys.stderr)
        bar, show = _optimize_bar(recipe.trials, args.quiet)
        runner = None
        try:
            runner = EpisodeRunner(controllers, workers=args.workers, servo=servo) if objective.tasks else None
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


def _report(args: argparse.Namespace) -> int:
    from tumblebot.sim.report import write_report

    if args.output.exists() and not args.output.is_dir():
        raise TumblebotError(f"-o {args.output} exists and is not a folder")
    _check_writable(args.output / "report.md", "-o")

    given = any(v is not None for v in (args.physics, args.motor_model, args.stall_torque))
    servo = _servo(args) if given else None  # else the studies' own
    if args.gait is not None and args.thesis_policies:
        raise TumblebotError("give --gait or --thesis-policies, not both")
    from tumblebot.sim.optimize import parse_xi_list

    xis = parse_xi_list(args.xi) if args.xi is not None else None
    path = write_report(args.storage, args.study, args.output, episodes=args.episodes, workers=args.workers,
                        seed=args.seed, slice_points=args.slice_points, progress=not args.quiet,
                        controller=args.gait or ("thesis-policy" if args.thesis_policies else None), servo=servo,
                        allow_servo_mismatch=args.allow_servo_mismatch, xis=xis)
    print(f"wrote {path}")
    return 0


def _servo(args: argparse.Namespace) -> Any:
    """The physics profile of ``--physics`` (default ``thesis``) with the ``--motor-model``
    and ``--stall-torque`` shorthands applied."""
    from tumblebot.sim.physics import PhysicsProfile

    return PhysicsProfile.from_arguments(args.physics, args.motor_model, args.stall_torque)


_check_writable = check_writable  # the name host/, sim/hardware/ and this module pass around


def _add_mismatch_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--allow-servo-mismatch", action="store_true",
                   help="use a policy under a servo other than the one its model card says it was trained under")


def _add_physics_argument(p: argparse.ArgumentParser, what: str = "the world of every episode") -> None:
    p.add_argument("--physics", default=None, metavar="NAME|FILE",
                   help=f"physics profile: {what} (servo, floor friction, latency, motor noise): the built-in "
                        "thesis (default) or a JSON file (tumblebot physics show; docs/physics.md)")


def _add_servo_arguments(p: argparse.ArgumentParser) -> None:
    # No simulator import here: building the parser stays fast (--help, bad arguments).
    _add_physics_argument(p)
    p.add_argument("--motor-model", choices=("dc", "velocity"), default=None,
                   help="servo model: dc (torque falls linearly from the stall torque to zero at the free "
                        "speed) or velocity (velocity control capped at the stall torque); default the "
                        "profile's (dc)")
    p.add_argument("--stall-torque", type=_stall_torque, default=None, metavar="N·m",
                   help="servo stall torque in N·m (default 0.582, the thesis's motor constants; "
                        "a predecessor-like strong servo is --motor-model velocity --stall-torque 10)")


def _stall_torque(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and 0.0 < value <= MAX_STALL_TORQUE):
        raise argparse.ArgumentTypeError(f"{text} N·m must be in (0, {MAX_STALL_TORQUE:g}]")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= value < 2**63:
        raise argparse.ArgumentTypeError(f"{value} must be a non-negative integer")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be at least 1")
    return value


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= value <= 1000:
        raise argparse.ArgumentTypeError(f"{value} must be an integer from 0 to 1000")
    return value


def _positive_float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def _add_power_command(sub: Subcommands) -> None:
    """The ``power`` command."""
    p = sub.add_parser("power", help="power model: mass and e(w) in W/m for a design",
                       description="Print the robot's mass, the two half-tumble terms and e(w) (W/m) "
                                   "from the thesis's power model (with the squares the thesis dropped "
                                   "restored). Lengths in metres.")
    for name, desc in (("x", "body width along the leg axis"), ("y", "side-profile dimension"),
                       ("z", "side-profile dimension"), ("l", "leg length")):
        p.add_argument(name, type=_positive_float, help=f"{desc}, m")
    p.add_argument("--json", action="store_true", help="print one JSON object (keys include mass, e)")
    p.add_argument("--allow-out-of-bounds", action="store_true", help="accept designs outside the bounds")
    p.set_defaults(func=_power)


def _add_urdf_command(sub: Subcommands) -> None:
    """The ``urdf`` command."""
    p = sub.add_parser("urdf", help="export a design's robot model as URDF",
                       description="Write the same model the simulator builds as a URDF file.")
    p.add_argument("--design", default=XI3_ROBOT_TEXT, metavar="X,Y,Z,L",
                   help="design in metres (default: the thesis's ξ = 3 robot)")
    p.add_argument("-o", "--output", type=Path, default=None, help="output file (default: stdout)")
    p.add_argument("--allow-out-of-bounds", action="store_true", help="accept designs outside the bounds")
    p.set_defaults(func=_urdf)


def _add_sim_command(sub: Subcommands) -> None:
    """The ``sim`` command."""
    p = sub.add_parser("sim", help="run one episode with a scripted gait (optionally as a GIF)",
                       description="Run one 20-step episode of a task with a fixed gait and print "
                                   "the trajectory and the final-state reward R.")
    p.add_argument("--task", default="nav-flat", help=TASK_CHOICES)
    p.add_argument("--design", default=XI3_ROBOT_TEXT, metavar="X,Y,Z,L", help="design in metres")
    p.add_argument("--gait", default="forward",
                   help="forward, reverse, alternate, pulse, spin, stop, random, or goto (the closed-loop "
                        "navigation controller; nav-flat and nav-terrain only)")
    p.add_argument("--seed", type=_seed, default=0, help="episode seed (start pose, terrain, noise)")
    _add_servo_arguments(p)
    p.add_argument("--randomize", action="store_true",
                   help="apply domain randomisation (masses, friction, motor noise, latency, start pose)")
    p.add_argument("--video", type=Path, default=None, metavar="OUT.gif", help="write an animated GIF")
    p.add_argument("--allow-out-of-bounds", action="store_true", help="accept designs outside the bounds")
    p.set_defaults(func=_sim)


def _add_train_command(sub: Subcommands) -> None:
    """The ``train`` command."""
    p = sub.add_parser("train", help="train a PPO policy for a task (checkpoints, resume)",
                       description="Train a PPO policy with domain randomisation over the design bounds. "
                                   "A run folder holds config.json, checkpoints, episodes.csv, TensorBoard "
                                   "logs and learning_curve.png; a stopped run continues with --resume.")
    p.add_argument("--task", default=None, help=TASK_CHOICES + " (default nav-flat; a resumed run keeps its own)")
    p.add_argument("--steps", type=_positive_int, default=None,
                   help="total environment steps (default 2000000; with --resume, a new total for the run). PPO "
                        "collects whole rollouts (n_steps x envs), so a run may end a little past it")
    p.add_argument("--envs", type=int, default=None, help="parallel environments (default: one per core)")
    p.add_argument("--seed", type=int, default=None, help="seed (default 0)")
    p.add_argument("--checkpoint-every", type=_positive_int, default=None,
                   help="environment steps between checkpoints (default 50000)")
    p.add_argument("--config", type=Path, default=None, help="JSON file of TrainConfig fields")
    p.add_argument("--run-dir", type=Path, default=None, help="run folder (default runs/TASK-TIMESTAMP)")
    p.add_argument("--resume", action="store_true", help="continue the run in --run-dir from its last checkpoint")
    _add_physics_argument(p, "the world to train under (recorded in the model card)")
    p.add_argument("--motor-model", choices=("dc", "velocity"), default=None,
                   help="servo model to train under (default the profile's, dc; recorded in the model card)")
    p.add_argument("--stall-torque", type=_stall_torque, default=None, metavar="N·m",
                   help="servo stall torque to train under (default 0.582, the thesis's motor constants)")
    p.add_argument("--init-from", type=Path, default=None, metavar="CHECKPOINT",
                   help="start a new run from the weights of another run's checkpoint (e.g. "
                        "runs/distance-flat/latest.zip for incline); the networks must match, and the "
                        "observation, net_arch, servo and design draw default to that run's")
    p.add_argument("--observation", choices=OBSERVATION_LAYOUTS, default=None,
                   help="policy input: the thesis's 9 numbers; context: those plus the design, the steps left "
                        "and the previous observation; memory: context plus goto's motion estimates; residual: "
                        "memory plus the action goto would take; dual: residual plus the action of goto with "
                        "its second pinned settings (default thesis)")
    p.set_defaults(func=_train)


def _add_imitate_command(sub: Subcommands) -> None:
    """The ``imitate`` command."""
    p = sub.add_parser("imitate", help="behaviour-clone the goto controller (DAgger): a warm start for train",
                       description="Train a context-, memory-, residual- or dual-observation policy to do what "
                                   "the goto controller would, with DAgger: goto drives the first iteration, the "
                                   "student the rest, and goto labels every state. The run folder is a training run: "
                                   "export it, or fine-tune it with tumblebot train --init-from RUN/latest.zip.")
    p.add_argument("--task", default="nav-flat", help="nav-flat or nav-terrain")
    p.add_argument("--run-dir", type=Path, required=True, help="new run folder")
    p.add_argument("--iterations", type=_positive_int, default=8, help="DAgger iterations (default 8)")
    p.add_argument("--episodes", type=_positive_int, default=500, help="episodes per iteration (default 500)")
    p.add_argument("--updates", type=_positive_int, default=4000,
                   help="gradient steps after each iteration (default 4000)")
    p.add_argument("--net-arch", type=_net_arch, default=[256, 256], metavar="N,N",
                   help="hidden layer sizes (default 256,256)")
    p.add_argument("--observation", choices=OBSERVATION_LAYOUTS[1:], default="context",
                   help="student input: context (the thesis's 9 numbers, the design, the steps left, the previous "
                        "observation), memory (context plus goto's motion estimates), residual (memory plus the "
                        "action goto would take) or dual (residual plus the action of goto with its second "
                        "pinned settings; needs --choice; default context)")
    p.add_argument("--choice", type=Path, default=None, metavar="CHOICE.json",
                   help="with --observation dual: which goto settings suit which body (python -m "
                        "tumblebot.training.choice fit); the teacher follows the better one on each body")
    p.add_argument("--envs", type=int, default=None, help="parallel environments (default: one per core)")
    p.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    _add_servo_arguments(p)
    p.add_argument("--refine", type=Path, default=None, metavar="RUN",
                   help="continue from the imitation run RUN toward a privileged teacher: goto, with a clairvoyant "
                        "search over the episode's last --lookahead steps (every action tried from a snapshot, "
                        "then goto to the end); the student drives every iteration, --envs worker processes")
    p.add_argument("--lookahead", type=_positive_int, default=4, help="steps the search labels (default 4)")
    p.add_argument("--draws", type=_non_negative_int, default=0, metavar="K",
                   help="with --refine: score each action by the mean over K futures of motor noise and latency "
                        "drawn anew, so the teacher does not see the noise to come (default 0: the episode's own "
                        "future, clairvoyant)")
    p.add_argument("--search-target", choices=("best", "expected"), default="best",
                   help="with --refine: what the student learns in the searched steps: best, the action the "
                        "search found best in each state; expected, the action with the best mean score over the "
                        "states the student cannot tell apart (it maximises the scores' expectation under its own "
                        "action distribution, and keeps goto's action unless another is more than 0.01 R better; "
                        "default best)")
    p.set_defaults(func=_imitate)


def _add_curve_command(sub: Subcommands) -> None:
    """The ``curve`` command."""
    p = sub.add_parser("curve", help="learning curves of training runs, following their warm starts",
                       description="Draw each run's final-state R over environment steps, with the runs it was "
                                   "warm-started from (its config's init_from, followed back) before it on the "
                                   "same axis. Needs only the runs' episodes.csv and config.json (no torch).")
    p.add_argument("runs", type=Path, nargs="+", metavar="RUN", help="run folders (e.g. training/checkpoints/nav-flat)")
    p.add_argument("-o", "--output", type=Path, required=True, help="PNG file to write")
    p.set_defaults(func=_curve)


def _add_export_command(sub: Subcommands) -> None:
    """The ``export`` command."""
    p = sub.add_parser("export", help="export a trained run to ONNX with a model card (and evaluate it)",
                       description="Write one self-contained ONNX file (dynamic batch, no side data) and "
                                   "its model card (JSON, beside it), then evaluate the policy against "
                                   "scripted gaits and a random policy and record that in the card.")
    p.add_argument("run", type=Path, help="run folder (uses RUN/latest.zip) or a checkpoint .zip")
    p.add_argument("-o", "--output", type=Path, required=True, help="output .onnx file, e.g. policies/nav-flat.onnx")
    p.add_argument("--task", default=None, help="task (default: the run's, from its config.json; a navigation "
                                                "run may be exported for either navigation task)")
    p.add_argument("--eval-episodes", type=_non_negative_int, default=240,
                   help="episodes per design for the card's evaluation (default 240; 0: skip it)")
    p.add_argument("--seed", type=int, default=0, help="evaluation seed (default 0)")
    p.add_argument("--workers", type=_positive_int, default=1, help="evaluation worker processes (default 1)")
    p.add_argument("--note", default=None, help="free text for the card: status, what was tried, known limits "
                                                "(default none)")
    p.add_argument("--baselines-from", type=Path, default=None, metavar="CARD.json",
                   help="reuse the gait baselines of an earlier card of the same task, episodes and seed (checked: "
                        "its best fixed gait is re-run and must give the recorded mean exactly)")
    p.set_defaults(func=_export)


def _add_evaluate_command(sub: Subcommands) -> None:
    """The ``evaluate`` command."""
    p = sub.add_parser("evaluate", help="evaluate a policy (or a gait) on a design: mean R with a 95 %% CI",
                       description="Run N episodes of a task on one design with the bundled ONNX policy "
                                   "(or --policy / --gait). Episode i with seed S is the same whatever "
                                   "--workers is, and the same draws are used for every design.")
    p.add_argument("--task", required=True, help=TASK_CHOICES)
    p.add_argument("--design", required=True, metavar="X,Y,Z,L", help="design in metres")
    p.add_argument("--episodes", type=int, default=240, help="number of episodes (default 240)")
    p.add_argument("--seed", type=_seed, default=0, help="evaluation seed")
    p.add_argument("--workers", type=int, default=1, help="worker processes")
    p.add_argument("--policy", type=Path, default=None, help="ONNX policy (default: the bundled one)")
    p.add_argument("--gait", default=None,
                   help="evaluate a scripted gait (forward, spin, …) or goto, the closed-loop navigation "
                        "controller, instead of a policy")
    _add_servo_arguments(p)
    _add_mismatch_argument(p)
    p.add_argument("--xi", type=float, default=None, help="also report f = R/(e+1)^xi")
    p.add_argument("--csv", type=Path, default=None, help="write per-episode results to this CSV")
    p.add_argument("--json", action="store_true", help="print one JSON object (mean_R, ci95, e, episodes, …)")
    p.add_argument("--allow-out-of-bounds", action="store_true", help="accept designs outside the bounds")
    p.set_defaults(func=_evaluate)


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
    p.add_argument("--seed", type=_seed, default=0, help="seed of the episodes and start-up designs (default 0)")
    p.add_argument("--variant", choices=("thesis", "monotone"), default="thesis",
                   help="wrapper for R < 0: the thesis's R/(e+1)^xi or the monotone R*(e+1)^xi (default thesis)")
    p.add_argument("--json", type=Path, help="also write the study summary as JSON to this file")
    p.add_argument("--gait", default=None, metavar="goto",
                   help="drive the episodes with goto, the hand-written closed-loop navigation controller (navigation "
                        "tasks), or a scripted gait, instead of each task's bundled policy; recorded in the study")
    p.add_argument("--thesis-policies", action="store_true",
                   help="drive the episodes with the bundled policies that see only the thesis's 9-number "
                        "observation (policies/TASK-thesis.onnx where the best one also takes the design), as the "
                        "thesis did; recorded in the study")
    _add_servo_arguments(p)
    _add_mismatch_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    # Ctrl-C stays latched until optimize's StopFlag takes it over: nothing in its start-up
    # (imports, policy checks) can lose it.
    p.set_defaults(func=_optimize, holds_interrupts=True)


def _add_report_command(sub: Subcommands) -> None:
    """The ``report`` command."""
    p = sub.add_parser(
        "report", help="write a report (Markdown + plots) of optimisation studies",
        description="Write DIR/report.md with plots: the optimum of each study re-evaluated on fresh episodes, the "
                    "Table 3.1 and 3.2 equivalents next to the thesis's values, the universal-optimum check, "
                    "objective and best design vs trial, one-parameter slices through the optimum, and e(w).")
    p.add_argument("--storage", required=True, help="Optuna storage URL the studies live in")
    p.add_argument("--study", action="append", required=True,
                   help="study name; repeat for several (e.g. one per xi, one per task)")
    p.add_argument("-o", "--output", type=Path, required=True, help="report folder (created)")
    p.add_argument("--xi", default=None, metavar="XIS",
                   help="for front studies (optimize --front): the xi values to read an optimum for, e.g. "
                        "0,1,3,inf (default: the study's own list); one Table 3.1 row each")
    p.add_argument("--episodes", type=int, help="episodes per task for every re-evaluation (default: the "
                                                "studies' full batch)")
    p.add_argument("--slice-points", type=int, default=7, help="points per one-parameter slice (default 7)")
    p.add_argument("--workers", type=int, default=1, help="processes running episodes (default 1)")
    p.add_argument("--seed", type=_seed, default=1, help="seed of the re-evaluation episodes, which should differ "
                                                       "from the studies' (default 1)")
    p.add_argument("--gait", default=None, metavar="goto",
                   help="re-evaluate every design with goto (or a gait) instead of the controller the studies used "
                        "(default: theirs, which must then agree)")
    p.add_argument("--thesis-policies", action="store_true",
                   help="re-evaluate with the bundled thesis-observation policies (see optimize --thesis-policies)")
    _add_physics_argument(p, "re-evaluate under this world (default: the studies', which must agree)")
    p.add_argument("--motor-model", choices=("dc", "velocity"), default=None,
                   help="re-evaluate under this servo model (default: the studies', which must agree)")
    p.add_argument("--stall-torque", type=_stall_torque, default=None, metavar="N·m",
                   help="re-evaluate with this stall torque (default: the studies')")
    _add_mismatch_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_report)


def _add_demo_command(sub: Subcommands) -> None:
    """The ``demo`` command."""
    p = sub.add_parser("demo", help="scripted episodes, the bundled policies and the power table",
                       description="A tour of the simulator in about a minute: a scripted episode of each of "
                                   "the four tasks, the bundled policies on the same robot, and the "
                                   "power model against thesis Table 3.1.")
    p.add_argument("--video-dir", type=Path, default=None, help="also write one GIF per task here")
    p.set_defaults(func=_demo)


def build_parser() -> argparse.ArgumentParser:
    from tumblebot import __version__
    from tumblebot.host.cli import add_commands as add_host_commands
    from tumblebot.sim.hardware.commands import add_command as add_build_command
    from tumblebot.sim.physics_command import add_command as add_physics_command

    parser = argparse.ArgumentParser(
        prog="tumblebot",
        description="Simulate, train, optimise and deploy two-legged tumbling robots.",
    )
    parser.add_argument("--version", action="version", version=f"tumblebot {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    _add_power_command(sub)
    _add_urdf_command(sub)
    _add_sim_command(sub)
    _add_train_command(sub)
    _add_imitate_command(sub)
    _add_curve_command(sub)
    _add_export_command(sub)
    _add_evaluate_command(sub)
    _add_optimize_command(sub)
    _add_report_command(sub)
    add_build_command(sub, _positive_float, _check_writable)
    add_host_commands(sub, _positive_int, _check_writable)
    add_physics_command(sub)
    _add_demo_command(sub)
    return parser


#: which extra installs each third-party package a command may import (pyproject.toml)
EXTRA_OF_MODULE = {
    "numpy": "sim", "scipy": "sim", "pybullet": "sim", "gymnasium": "sim", "PIL": "sim", "matplotlib": "sim",
    "tqdm": "sim", "onnxruntime": "sim", "optuna": "opt", "psycopg": "opt", "sqlalchemy": "opt",
    "optuna_dashboard": "opt", "torch": "train", "stable_baselines3": "train", "tensorboard": "train",
    "onnx": "train", "onnxscript": "train", "build123d": "build", "ezdxf": "build", "trimesh": "build",
    "motioncapture": "host", "mcap": "host", "foxglove": "host", "serial": "agent",
}


def missing_extra(exc: ImportError) -> str | None:
    """One line naming the extra that installs a missing package, or None if it is none of ours
    (a broken install, a bug: those keep their traceback)."""
    name = (exc.name or "").split(".")[0]
    extra = EXTRA_OF_MODULE.get(name)
    if extra is None:
        return None
    return (f"this command needs the '{extra}' extra ({name} is not installed): "
            f"pip install 'tumblebot[{extra}]' (a Raspberry Pi needs only tumblebot-agent, from the 'agent' extra)")


def main(argv: Sequence[str] | None = None) -> int:
    interrupts.hold()  # Ctrl-C while starting up is recorded, not raised mid-import (tumblebot.interrupts)
    try:
        return _dispatch(argv)
    finally:
        with contextlib.suppress(KeyboardInterrupt):  # too late to matter: the command has ended
            interrupts.release()  # Python's handler back (an in-process caller keeps Ctrl-C)


def _dispatch(argv: Sequence[str] | None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "holds_interrupts", False):
            interrupts.release()  # raises here, at a known point, if Ctrl-C came meanwhile
    except KeyboardInterrupt:
        print("tumblebot: interrupted", file=sys.stderr)
        return 130
    try:
        code = int(args.func(args))
        interrupts.release()  # a Ctrl-C that a holding command's own stop flag never saw
        return code
    except TumblebotError as exc:
        print(f"tumblebot: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("tumblebot: interrupted", file=sys.stderr)
        return 130
    except ImportError as exc:  # Ctrl-C inside a C extension's import surfaces as ImportError
        if isinstance(exc.__cause__ or exc.__context__, KeyboardInterrupt):
            print("tumblebot: interrupted", file=sys.stderr)
            return 130
        missing = missing_extra(exc)
        if missing is None:
            raise
        print(f"tumblebot: error: {missing}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
