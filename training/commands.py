"""Training's commands: ``train``, ``imitate``, ``curve`` and ``export``.

torch and stable-baselines3 are imported inside the handlers only, so building the parser
(``tumblebot --help``) never loads them.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from tumblebot.cliargs import (
    Subcommands,
    add_physics_argument,
    add_servo_arguments,
    check_writable,
    check_writable_folder,
    count,
    non_negative_int,
    positive_float,
    positive_int,
    reach_bound,
    seed_type,
    stall_torque,
)
from tumblebot.defaults import OBSERVATION_LAYOUTS
from tumblebot.errors import TumblebotError
from tumblebot.sim.observation import CHOICE_LAYOUTS
from tumblebot.sim.world.physics import profile_from_args
from tumblebot.sim.world.tasks import TASK_CHOICES


def _train(args: argparse.Namespace) -> int:
    from tumblebot.training.ppo import TrainingInterrupted

    try:
        return _train_run(args)
    except TrainingInterrupted as stopped:
        print(f"\n{stopped}", file=sys.stderr)
        return 130


def _train_run(args: argparse.Namespace) -> int:
    from tumblebot.sim.world.tasks import get_task

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
        overrides.update(profile_from_args(args).as_fields())
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
    from tumblebot.sim.control.goto import check_navigation_task
    from tumblebot.sim.observation import teacher_name
    from tumblebot.training.ppo import TrainingInterrupted

    if args.refine is not None:
        return _refine(args)

    task = check_navigation_task(args.task)
    from tumblebot.training.config import TrainConfig
    from tumblebot.training.imitation import ImitationConfig, imitate

    settings = ImitationConfig(iterations=args.iterations, episodes=args.episodes, updates=args.updates,
                               learning_rate=args.learning_rate, learning_rate_end=args.learning_rate_end)
    config = TrainConfig(task=task, observation=args.observation, tumbling_designs_only=True, net_arch=args.net_arch,
                         n_envs=args.envs if args.envs is not None else 0, seed=args.seed,
                         **profile_from_args(args).as_fields())
    teacher = teacher_name(args.observation)
    if args.choice is not None:
        teacher += f" under the setting {args.choice} picks for each body"
    print(f"imitating {teacher} on {task}: {settings.iterations} DAgger iterations of {settings.episodes} episodes, "
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

    settings = ImitationConfig(iterations=args.iterations, episodes=args.episodes, updates=args.updates,
                               learning_rate=args.learning_rate, learning_rate_end=args.learning_rate_end)
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

    check_writable(args.output, "-o")
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
    from tumblebot.sim.world.tasks import get_task, same_goal
    from tumblebot.training.export import export_onnx, load_run, wall_seconds_at, write_card

    if args.output.suffix != ".onnx":
        raise TumblebotError(f"-o {args.output}: the output must end in .onnx")
    previous = None
    if args.baselines_from is not None:  # read before anything is written (it may be the card being replaced)
        try:
            previous = json.loads(args.baselines_from.read_text()).get("evaluation")
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError) as exc:
            raise TumblebotError(f"--baselines-from {args.baselines_from}: not a readable model card ({exc})") from None
    check_writable(args.output, "-o")
    check_writable(args.output.with_suffix(".json"), "-o")
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
        from tumblebot.sim.control.policy import card_path
        from tumblebot.training.card_eval import card_evaluation, comparison_summary, comparison_table

        evaluation = card_evaluation(args.output, task.name, args.eval_episodes, args.seed, args.workers, previous,
                                     confirm=args.confirm_episodes)
        card = json.loads(card_path(args.output).read_text())
        card["evaluation"] = evaluation
        card_path(args.output).write_text(json.dumps(card, indent=2) + "\n")
        for label, entry in evaluation["designs"].items():
            lo, hi = entry["ci95"]
            print(f"{label}: mean R {entry['mean_R']:.3f} [{lo:.3f}, {hi:.3f}], best fixed gait "
                  f"{entry['best_fixed_gait']} {entry['baselines'][entry['best_fixed_gait']]['mean_R']:.3f} "
                  f"(p = {entry['p_vs_best_fixed_gait']:.2g}), random {entry['baselines']['random']['mean_R']:.3f}")
        for which, comparison in evaluation.get("against_hand_written", {}).items():
            print(f"against the hand-written controllers, {which} designs: {comparison_summary(comparison)}")
            print(comparison_table(comparison))
    return 0


def _add_train_command(sub: Subcommands) -> None:
    """The ``train`` command."""
    p = sub.add_parser("train", help="train a PPO policy for a task (checkpoints, resume)",
                       description="Train a PPO policy with domain randomisation over the design bounds. "
                                   "A run folder holds config.json, checkpoints, episodes.csv, TensorBoard "
                                   "logs and learning_curve.png; a stopped run continues with --resume.")
    p.add_argument("--task", default=None, help=TASK_CHOICES + " (default nav-flat; a resumed run keeps its own)")
    p.add_argument("--steps", type=positive_int, default=None,
                   help="total environment steps (default 2000000; with --resume, a new total for the run). PPO "
                        "collects whole rollouts (n_steps x envs), so a run may end a little past it")
    p.add_argument("--envs", type=int, default=None, help="parallel environments (default: one per core)")
    p.add_argument("--seed", type=int, default=None, help="seed (default 0)")
    p.add_argument("--checkpoint-every", type=positive_int, default=None,
                   help="environment steps between checkpoints (default 50000)")
    p.add_argument("--config", type=Path, default=None, help="JSON file of TrainConfig fields")
    p.add_argument("--run-dir", type=Path, default=None, help="run folder (default runs/TASK-TIMESTAMP)")
    p.add_argument("--resume", action="store_true", help="continue the run in --run-dir from its last checkpoint")
    add_physics_argument(p, "the world to train under (recorded in the model card)")
    p.add_argument("--motor-model", choices=("dc", "velocity"), default=None,
                   help="servo model to train under (default the profile's, dc; recorded in the model card)")
    p.add_argument("--stall-torque", type=stall_torque, default=None, metavar="N·m",
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
    p.add_argument("--iterations", type=positive_int, default=8, help="DAgger iterations (default 8)")
    p.add_argument("--episodes", type=positive_int, default=500, help="episodes per iteration (default 500)")
    p.add_argument("--updates", type=positive_int, default=4000,
                   help="gradient steps after each iteration (default 4000)")
    p.add_argument("--learning-rate", type=positive_float, default=1e-3, metavar="LR",
                   help="Adam step size of the fits (default 1e-3)")
    p.add_argument("--learning-rate-end", type=positive_float, default=None, metavar="LR",
                   help="let each fit's step size fall linearly to this by its last update (default: constant); "
                        "1e-4 fits the rare states where a body's goto settings disagree")
    p.add_argument("--net-arch", type=_net_arch, default=[256, 256], metavar="N,N",
                   help="hidden layer sizes (default 256,256)")
    p.add_argument("--observation", choices=OBSERVATION_LAYOUTS[1:], default="context",
                   help="student input: context (the thesis's 9 numbers, the design, the steps left, the previous "
                        "observation), memory (context plus goto's motion estimates), residual (memory plus the "
                        "action goto would take), dual (residual plus the action of goto with its second "
                        "pinned settings; needs --choice), dual-plan (dual's fields from two gotos with plan's "
                        "estimates; needs a --choice swept for it) or tri-plan (dual-plan plus the action of plan "
                        "with the wider turning short legs prefer; needs a --choice fitted for it); default context")
    p.add_argument("--choice", type=Path, default=None, metavar="CHOICE.json",
                   help="with --observation dual, dual-plan or tri-plan: which goto settings suit which body "
                        "(tumblebot choice fit); the teacher follows the better one on each body")
    p.add_argument("--envs", type=int, default=None, help="parallel environments (default: one per core)")
    p.add_argument("--seed", type=seed_type, default=0, help="seed (default 0)")
    add_servo_arguments(p)
    p.add_argument("--refine", type=Path, default=None, metavar="RUN",
                   help="continue from the imitation run RUN toward a privileged teacher: goto, with a clairvoyant "
                        "search over the episode's last --lookahead steps (every action tried from a snapshot, "
                        "then goto to the end); the student drives every iteration, --envs worker processes")
    p.add_argument("--lookahead", type=positive_int, default=4, help="steps the search labels (default 4)")
    p.add_argument("--draws", type=non_negative_int, default=0, metavar="K",
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
    p.add_argument("--eval-episodes", type=none_or_at_least_two, default=240,
                   help="episodes per design for the card's evaluation, at least 2 for an interval and a p-value "
                        "(default 240; 0: skip it)")
    p.add_argument("--confirm-episodes", type=none_or_at_least_two, default=None, metavar="N",
                   help="navigation tasks: measure a design where the policy is behind the strongest hand-written "
                        "controller again on N fresh episodes before the card calls it behind (default five "
                        "times the first measurement's episodes, at most 240; 0: do not; else at least 2)")
    p.add_argument("--seed", type=int, default=0, help="evaluation seed (default 0)")
    p.add_argument("--workers", type=positive_int, default=1, help="evaluation worker processes (default 1)")
    p.add_argument("--note", default=None, help="free text for the card: status, what was tried, known limits "
                                                "(default none)")
    p.add_argument("--baselines-from", type=Path, default=None, metavar="CARD.json",
                   help="reuse the gait baselines of an earlier card of the same task, episodes and seed (checked: "
                        "its best fixed gait is re-run and must give the recorded mean exactly)")
    p.set_defaults(func=_export)


def _choice(args: argparse.Namespace) -> int:
    """``tumblebot choice sweep|fit``: where goto's later settings beat its first, and the
    teacher's rules fitted to it (:mod:`tumblebot.training.choice`)."""
    import numpy as np

    from tumblebot.sim.control.goto import check_navigation_task
    from tumblebot.sim.observation import teacher_name
    from tumblebot.sim.world.design import Design, tumbling_designs
    from tumblebot.training.choice import SEEDING, GotoChoice, check_compared, reach, read_sweep, sweep
    from tumblebot.training.config import TrainingError

    if args.choice_command == "fit":
        check_writable(args.output, "-o")
        records = [record for path in args.sweep for record in read_sweep(path)]
        choice = GotoChoice.fit(records, args.layout)
        args.output.write_text(choice.to_json())
        print(choice.summary())
        return 0
    check_writable(args.out, "--out")
    task = check_navigation_task(args.task)
    compared = list(check_compared(args.layout, args.compare))
    physics = profile_from_args(args)
    done = read_sweep(args.out) if args.out.exists() else []
    drawn = tumbling_designs(args.designs, args.seed)
    indices = [k for k, d in enumerate(drawn) if args.reach_below is None or reach(d.as_tuple())[0] < args.reach_below]
    designs = [drawn[k] for k in indices]
    for k, record in enumerate(done):  # continue only the same sweep
        if record.get("seeding") != SEEDING:
            raise TrainingError(f"{args.out} was swept by an earlier tumblebot, which seeded each design's "
                                "episodes its own way: start a new file")
        same = (k < len(designs) and record.get("seed") == args.seed and record.get("episodes") == args.episodes
                and record.get("physics") == physics.digest() and record.get("layout", "dual") == args.layout
                and record.get("task", "nav-flat") == task and record.get("compared", [2]) == compared
                and record.get("index", k) == indices[k]
                and np.allclose(record["design"], designs[k].as_tuple()))
        if not same:
            below = "" if args.reach_below is None else f" --reach-below {args.reach_below:g}"
            raise TrainingError(f"{args.out} holds another sweep (line {k + 1} is not design {k + 1} of "
                                f"--designs {args.designs} --episodes {args.episodes} --seed {args.seed} "
                                f"--layout {args.layout} --compare {' '.join(map(str, compared))}{below} "
                                f"--task {task} under the {physics.describe()})")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    first = teacher_name(args.layout)  # the record's "goto" key is the first setting's R
    with args.out.open("a") as out:
        for record in sweep(designs, args.episodes, args.seed, args.workers, done=len(done), physics=physics,
                            layout=args.layout, task=task, compared=compared, indices=indices):
            out.write(json.dumps(record) + "\n")
            out.flush()
            later = ", ".join(f"setting {k} {d:+.3f} ± {e:.3f}" for k, d, e in
                              zip(record["compared"], record["differences"], record["errors"], strict=True))
            print(f"{record['index'] + 1}/{len(drawn)} {Design.from_sequence(record['design'])}: "
                  f"{first} {record['goto']:.3f}, {later}", flush=True)
    return 0


def _add_choice_command(sub: Subcommands) -> None:
    """The ``choice`` command: the sweep and the fit behind the bundled navigation policy's teacher."""
    p = sub.add_parser("choice", help="where goto's later settings beat its first: a sweep over designs, "
                                      "and the teacher's rules fitted to it (for imitate --choice)",
                       description="sweep: goto under a layout's pinned settings on designs drawn over the space "
                                   "(resumable: the same command continues the file). fit: the thresholds on "
                                   "l/r the teacher uses, fitted to sweeps. Ctrl-C stops; the same command "
                                   "resumes.")
    csub = p.add_subparsers(dest="choice_command", required=True, metavar="{sweep,fit}")
    s = csub.add_parser("sweep", help="goto under a layout's settings on designs drawn over the space (resumable)")
    s.add_argument("--designs", type=positive_int, default=240, help="designs to sweep (default 240)")
    s.add_argument("--episodes", type=at_least_two, default=48, help="paired episodes per design (default 48)")
    s.add_argument("--seed", type=seed_type, default=3,
                   help="designs and episodes (default 3; keep it apart from evaluation seeds)")
    s.add_argument("--workers", type=positive_int, default=2, help="worker processes (default 2)")
    s.add_argument("--out", type=Path, required=True, help="JSON-lines file; an existing one is continued")
    s.add_argument("--layout", choices=CHOICE_LAYOUTS, default="dual",
                   help="whose goto settings: dual (goto's defaults and the thesis robots' turning), "
                        "dual-plan (the same two with plan's steadier estimates) or tri-plan (dual-plan's and plan "
                        "with the wider turning short legs prefer); default dual")
    s.add_argument("--compare", type=int, nargs="+", default=None, metavar="K",
                   help="which later settings to compare with the first, by number (2: the second; default all)")
    s.add_argument("--reach-below", type=reach_bound, default=None, metavar="L/R",
                   help="sweep only the drawn designs whose reach l/r is below this (default all); the others "
                        "keep their numbers")
    s.add_argument("--task", default="nav-flat", help="nav-flat (default) or nav-terrain: the task the "
                                                     "settings are compared on")
    add_servo_arguments(s)
    f = csub.add_parser("fit", help="fit the teacher's choice (a threshold on l/r for each later setting) to sweeps")
    f.add_argument("sweep", type=Path, nargs="+", help="the sweeps' JSON-lines files (records of another layout "
                                                        "count where they compared the same two settings)")
    f.add_argument("--layout", choices=CHOICE_LAYOUTS, default=None,
                   help="the layout whose choice to fit (default: the one the sweeps were of)")
    f.add_argument("-o", "--output", type=Path, required=True, help="the choice file (JSON) imitate --choice takes")
    p.set_defaults(func=_choice)


def at_least_two(text: str) -> int:
    value = positive_int(text)
    if value < 2:
        raise argparse.ArgumentTypeError(f"{value} must be at least 2 (a paired difference needs two episodes)")
    return value


def none_or_at_least_two(text: str) -> int:
    """0 (none) or at least 2 episodes: one episode gives no interval and no paired test."""
    value = count(text)
    return value if value == 0 else at_least_two(text)


def add_commands(sub: Subcommands) -> None:
    """Add ``train``, ``imitate``, ``curve``, ``export`` and ``choice`` to the ``tumblebot`` parser's subcommands."""
    _add_train_command(sub)
    _add_imitate_command(sub)
    _add_curve_command(sub)
    _add_export_command(sub)
    _add_choice_command(sub)
