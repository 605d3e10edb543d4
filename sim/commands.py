"""The simulator's commands: ``power``, ``urdf``, ``sim``, ``evaluate`` and ``demo``.

Each handler parses nothing itself: it gets the parsed arguments, calls library code and
prints. Heavy imports (PyBullet, onnxruntime) happen inside the handlers, so building the
parser stays fast.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from tumblebot.cliargs import (
    Subcommands,
    add_mismatch_argument,
    add_servo_arguments,
    check_writable,
    number,
    seed_type,
)
from tumblebot.defaults import XI3_ROBOT_TEXT
from tumblebot.errors import TumblebotError
from tumblebot.sim.world.physics import profile_from_args
from tumblebot.sim.world.tasks import TASK_CHOICES


def _power(args: argparse.Namespace) -> int:
    from tumblebot.sim.world.design import Design
    from tumblebot.sim.world.mass import DEFAULT_MASS_MODEL
    from tumblebot.sim.world.power import power_breakdown

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
    from tumblebot.sim.world.design import Design
    from tumblebot.sim.world.robot import RobotModel, to_urdf

    w = Design.parse(args.design, allow_out_of_bounds=args.allow_out_of_bounds)
    if args.output is not None and str(args.output) != "-":
        check_writable(args.output, "-o")
    text = to_urdf(RobotModel.from_design(w))
    if args.output is None or str(args.output) == "-":
        sys.stdout.write(text)
    else:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text)
        print(f"wrote {args.output} ({w})", file=sys.stderr)
    return 0


def _sim(args: argparse.Namespace) -> int:
    from tumblebot.sim.evaluation.episode import run_gait_episode, write_animation
    from tumblebot.sim.world.design import Design
    from tumblebot.sim.world.tasks import get_task

    task = get_task(args.task)  # run_gait_episode checks the gait (or goto) for the task
    w = Design.parse(args.design, allow_out_of_bounds=args.allow_out_of_bounds)
    physics = profile_from_args(args)
    if args.video is not None:
        if args.video.suffix.lower() not in (".gif", ".png"):
            raise TumblebotError(f"--video {args.video}: the file must end in .gif (or .png)")
        check_writable(args.video, "--video")
    result = run_gait_episode(task.name, w, args.gait, args.seed, args.randomize, record=args.video is not None,
                              physics=physics)
    print(f"{task.name}: {task.description}")
    print(f"{w}, gait {args.gait!r}, {physics.describe()}, seed {args.seed}")
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
        check_writable(args.video_dir / "nav-flat.gif", "--video-dir")
    run_demo(sys.stdout, video_dir=args.video_dir)
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    import json

    from tumblebot.sim.control.policy import PolicyError, bundled_policy
    from tumblebot.sim.evaluation.evaluate import Driver, evaluate
    from tumblebot.sim.world.design import Design
    from tumblebot.sim.world.tasks import get_task

    task = get_task(args.task)
    w = Design.parse(args.design, allow_out_of_bounds=args.allow_out_of_bounds)
    if args.episodes < 1 or args.workers < 1:
        raise TumblebotError("--episodes and --workers must be at least 1")
    if args.gait is not None and args.policy is not None:
        raise TumblebotError("give --policy or --gait, not both")
    if args.xi is not None and not args.xi >= 0:
        raise TumblebotError(f"--xi {args.xi} must be >= 0 (or inf)")
    physics = profile_from_args(args)
    if args.gait is not None:
        controller = Driver.of_gait(args.gait)
    else:
        path = args.policy or bundled_policy(task.name)
        if args.policy is None and not path.is_file():
            raise PolicyError(f"no bundled policy for {task.name} ({path.name}); pass --policy FILE")
        controller = Driver("onnx", str(path), allow_servo_mismatch=args.allow_servo_mismatch)
    if args.csv is not None:
        check_writable(args.csv, "--csv")
    result = evaluate(task.name, w, controller, args.episodes, args.seed, args.workers, progress=not args.json,
                      physics=physics)
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
    print(f"{task.name}, {w}, {result.controller}, {physics.describe()}, {result.episodes} episodes, seed {args.seed}")
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


def _add_power_command(sub: Subcommands) -> None:
    """The ``power`` command."""
    p = sub.add_parser("power", help="power model: mass and e(w) in W/m for a design",
                       description="Print the robot's mass, the two half-tumble terms and e(w) (W/m) "
                                   "from the thesis's power model (with the squares the thesis dropped "
                                   "restored). Lengths in metres.")
    for name, desc in (("x", "body width along the leg axis"), ("y", "side-profile dimension"),
                       ("z", "side-profile dimension"), ("l", "leg length")):
        p.add_argument(name, type=number, help=f"{desc}, m")
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
                   help="forward, reverse, alternate, pulse, spin, stop, random, excite, or goto, plan or "
                        "plan-short (the closed-loop navigation controllers; nav-flat and nav-terrain only)")
    p.add_argument("--seed", type=seed_type, default=0, help="episode seed (start pose, terrain, noise)")
    add_servo_arguments(p)
    p.add_argument("--randomize", action="store_true",
                   help="apply domain randomisation (masses, friction, motor noise, latency, start pose)")
    p.add_argument("--video", type=Path, default=None, metavar="OUT.gif", help="write an animated GIF")
    p.add_argument("--allow-out-of-bounds", action="store_true", help="accept designs outside the bounds")
    p.set_defaults(func=_sim)


def _add_evaluate_command(sub: Subcommands) -> None:
    """The ``evaluate`` command."""
    p = sub.add_parser("evaluate", help="evaluate a policy (or a gait) on a design: mean R with a 95 %% CI",
                       description="Run N episodes of a task on one design with the bundled ONNX policy "
                                   "(or --policy / --gait). Episode i with seed S is the same whatever "
                                   "--workers is, and the same draws are used for every design.")
    p.add_argument("--task", required=True, help=TASK_CHOICES)
    p.add_argument("--design", required=True, metavar="X,Y,Z,L", help="design in metres")
    p.add_argument("--episodes", type=int, default=240, help="number of episodes (default 240)")
    p.add_argument("--seed", type=seed_type, default=0, help="evaluation seed")
    p.add_argument("--workers", type=int, default=1, help="worker processes")
    p.add_argument("--policy", type=Path, default=None, help="ONNX policy (default: the bundled one)")
    p.add_argument("--gait", default=None,
                   help="evaluate a scripted gait (forward, spin, …) or goto, plan or plan-short, the closed-loop "
                        "navigation controllers, instead of a policy")
    add_servo_arguments(p)
    add_mismatch_argument(p)
    p.add_argument("--xi", type=float, default=None, help="also report f = R/(e+1)^xi")
    p.add_argument("--csv", type=Path, default=None, help="write per-episode results to this CSV")
    p.add_argument("--json", action="store_true", help="print one JSON object (mean_R, ci95, e, episodes, …)")
    p.add_argument("--allow-out-of-bounds", action="store_true", help="accept designs outside the bounds")
    p.set_defaults(func=_evaluate)


def _add_demo_command(sub: Subcommands) -> None:
    """The ``demo`` command."""
    p = sub.add_parser("demo", help="scripted episodes, the bundled policies and the power table",
                       description="A tour of the simulator in about a minute: a scripted episode of each of "
                                   "the four tasks, the bundled policies on the same robot, and the "
                                   "power model against thesis Table 3.1.")
    p.add_argument("--video-dir", type=Path, default=None, help="also write one GIF per task here")
    p.set_defaults(func=_demo)


def add_commands(sub: Subcommands) -> None:
    """Add ``power``, ``urdf``, ``sim`` and ``evaluate`` to the ``tumblebot`` parser's subcommands."""
    _add_power_command(sub)
    _add_urdf_command(sub)
    _add_sim_command(sub)
    _add_evaluate_command(sub)


def add_demo_command(sub: Subcommands) -> None:
    """Add ``demo`` (last in the list of commands)."""
    _add_demo_command(sub)
