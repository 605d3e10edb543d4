"""The ``report`` command."""

from __future__ import annotations

import argparse
from pathlib import Path

from tumblebot.cliargs import (
    Subcommands,
    add_mismatch_argument,
    add_physics_argument,
    check_writable,
    seed_type,
    stall_torque,
)
from tumblebot.errors import TumblebotError
from tumblebot.sim.world.physics import profile_from_args


def _report(args: argparse.Namespace) -> int:
    from tumblebot.sim.report import write_report

    if args.output.exists() and not args.output.is_dir():
        raise TumblebotError(f"-o {args.output} exists and is not a folder")
    check_writable(args.output / "report.md", "-o")

    given = any(v is not None for v in (args.physics, args.motor_model, args.stall_torque))
    physics = profile_from_args(args) if given else None  # else the studies' own
    if args.gait is not None and args.thesis_policies:
        raise TumblebotError("give --gait or --thesis-policies, not both")
    from tumblebot.sim.optimize import parse_xi_list

    xis = parse_xi_list(args.xi) if args.xi is not None else None
    path = write_report(args.storage, args.study, args.output, episodes=args.episodes, workers=args.workers,
                        seed=args.seed, slice_points=args.slice_points, progress=not args.quiet,
                        controller=args.gait or ("thesis-policy" if args.thesis_policies else None), physics=physics,
                        allow_servo_mismatch=args.allow_servo_mismatch, xis=xis, policies=args.policy)
    print(f"wrote {path}")
    return 0


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
    p.add_argument("--seed", type=seed_type, default=1, help="seed of the re-evaluation episodes, which should differ "
                                                       "from the studies' (default 1)")
    p.add_argument("--gait", default=None, metavar="goto|plan",
                   help="re-evaluate every design with goto, plan or plan-short (or a gait) instead of the controller "
                        "the studies used (default: theirs, which must then agree)")
    p.add_argument("--policy", action="append", metavar="[TASK=]FILE",
                   help="re-evaluate TASK with this ONNX policy instead of the bundled one: the file a study was run "
                        "with (a study records each policy's SHA-256, and the report refuses a policy the studies "
                        "did not use); repeat for several tasks")
    p.add_argument("--thesis-policies", action="store_true",
                   help="re-evaluate with the bundled thesis-observation policies (see optimize --thesis-policies)")
    add_physics_argument(p, "re-evaluate under this world (default: the studies', which must agree)")
    p.add_argument("--motor-model", choices=("dc", "velocity"), default=None,
                   help="re-evaluate under this servo model (default: the studies', which must agree)")
    p.add_argument("--stall-torque", type=stall_torque, default=None, metavar="N·m",
                   help="re-evaluate with this stall torque (default: the studies')")
    add_mismatch_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_report)


def add_command(sub: Subcommands) -> None:
    """Add ``report`` to the ``tumblebot`` parser's subcommands."""
    _add_report_command(sub)
