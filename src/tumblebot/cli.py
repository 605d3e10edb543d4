"""The ``tumblebot`` command: a thin argument layer over plain functions.

Each subcommand parses its arguments, calls library code, and prints. Any
:class:`~tumblebot.errors.TumblebotError` becomes one ``tumblebot: error: …`` line and
exit status 2, never a traceback. Heavy imports (PyBullet) happen inside the handlers,
so ``tumblebot --help`` and ``tumblebot power`` stay fast.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from tumblebot.errors import TumblebotError


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
    text = to_urdf(RobotModel.from_design(w))
    if args.output is None or str(args.output) == "-":
        sys.stdout.write(text)
    else:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text)
        print(f"wrote {args.output} ({w})", file=sys.stderr)
    return 0


def _sim(args: argparse.Namespace) -> int:
    from tumblebot.sim.design import Design
    from tumblebot.sim.episode import run_gait_episode, write_animation
    from tumblebot.sim.gaits import get_gait
    from tumblebot.sim.randomization import Randomization
    from tumblebot.sim.tasks import get_task

    task = get_task(args.task)
    get_gait(args.gait)
    w = Design.parse(args.design, allow_out_of_bounds=args.allow_out_of_bounds)
    if args.video is not None and args.video.suffix.lower() not in (".gif", ".png"):
        raise TumblebotError(f"--video {args.video}: the file must end in .gif (or .png)")
    rnd = Randomization(design=False) if args.randomize else Randomization.off()
    result = run_gait_episode(task.name, w, args.gait, args.seed, rnd, args.motor_model,
                              record=args.video is not None)
    print(f"{task.name}: {task.description}")
    print(f"{w}, gait {args.gait!r}, motor model {args.motor_model}, seed {args.seed}")
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

    run_demo(sys.stdout, video_dir=args.video_dir)
    return 0


def _positive_float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def build_parser() -> argparse.ArgumentParser:
    from tumblebot import __version__

    parser = argparse.ArgumentParser(
        prog="tumblebot",
        description="Simulate, train, optimise and deploy two-legged tumbling robots.",
    )
    parser.add_argument("--version", action="version", version=f"tumblebot {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser("power", help="power model: mass and e(w) in W/m for a design",
                       description="Print the robot's mass, the two half-tumble terms and e(w) (W/m) "
                                   "from the thesis's power model (SPEC §3). Lengths in metres.")
    for name, desc in (("x", "body width along the leg axis"), ("y", "side-profile dimension"),
                       ("z", "side-profile dimension"), ("l", "leg length")):
        p.add_argument(name, type=_positive_float, help=f"{desc}, m")
    p.add_argument("--json", action="store_true", help="print one JSON object (keys include mass, e)")
    p.add_argument("--allow-out-of-bounds", action="store_true", help="accept designs outside the bounds")
    p.set_defaults(func=_power)

    p = sub.add_parser("urdf", help="export a design's robot model as URDF",
                       description="Write the same model the simulator builds as a URDF file.")
    p.add_argument("--design", default="0.292,0.129,0.098,0.136", metavar="X,Y,Z,L",
                   help="design in metres (default: the thesis's ξ = 3 robot)")
    p.add_argument("-o", "--output", type=Path, default=None, help="output file (default: stdout)")
    p.add_argument("--allow-out-of-bounds", action="store_true", help="accept designs outside the bounds")
    p.set_defaults(func=_urdf)

    p = sub.add_parser("sim", help="run one episode with a scripted gait (optionally as a GIF)",
                       description="Run one 20-step episode of a task with a fixed gait and print "
                                   "the trajectory and the final-state reward R.")
    p.add_argument("--task", default="nav-flat", help="nav-flat, nav-terrain, distance-flat or incline")
    p.add_argument("--design", default="0.292,0.129,0.098,0.136", metavar="X,Y,Z,L", help="design in metres")
    p.add_argument("--gait", default="forward",
                   help="forward, reverse, alternate, pulse, spin, stop or random")
    p.add_argument("--seed", type=int, default=0, help="episode seed (start pose, terrain, noise)")
    p.add_argument("--motor-model", choices=("dc", "velocity"), default="dc",
                   help="DC torque-speed servo model or velocity-with-force-cap")
    p.add_argument("--randomize", action="store_true",
                   help="apply domain randomisation (masses, friction, motor noise, latency, start pose)")
    p.add_argument("--video", type=Path, default=None, metavar="OUT.gif", help="write an animated GIF")
    p.add_argument("--allow-out-of-bounds", action="store_true", help="accept designs outside the bounds")
    p.set_defaults(func=_sim)

    p = sub.add_parser("demo", help="one scripted episode of each task and the power table",
                       description="What exists so far, in one minute: a scripted episode of each of "
                                   "the four tasks and the power model against thesis Table 3.1.")
    p.add_argument("--video-dir", type=Path, default=None, help="also write one GIF per task here")
    p.set_defaults(func=_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except TumblebotError as exc:
        print(f"tumblebot: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("tumblebot: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
