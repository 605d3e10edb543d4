"""The ``tumblebot build`` command: argument parsing and dispatch only."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tumblebot.errors import TumblebotError


def _design(args: argparse.Namespace) -> Any:
    from tumblebot.sim.world.design import Design

    if (args.design is None) == (args.storage is None):
        raise TumblebotError("give --design X,Y,Z,L, or --storage URL with --study NAME (a study's optimum)")
    if args.design is not None:
        if args.study is not None or args.xi is not None:
            raise TumblebotError("--study and --xi go with --storage, not with --design")
        return Design.parse(args.design, allow_out_of_bounds=args.allow_out_of_bounds)
    if args.study is None:
        raise TumblebotError("--storage needs --study NAME")
    from tumblebot.sim.optimize.storage import load_study, open_storage
    from tumblebot.sim.optimize.trials import best_candidate, front_optima

    study = load_study(open_storage(args.storage, must_exist=True), args.study)
    if args.xi is not None:
        if not (math.isinf(args.xi) or (math.isfinite(args.xi) and args.xi >= 0)):
            raise TumblebotError(f"--xi {args.xi} must be a non-negative number or inf")
        best = front_optima(study, (args.xi,)).get(args.xi)
    else:
        best = best_candidate(study)
    if best is None:
        raise TumblebotError(f"study {args.study!r} has no finished trial to build")
    return best.design


def _build(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from tumblebot.sim.world.catalogue import servo
    from tumblebot.sim.world.mass import DEFAULT_MASS_MODEL

    spec = servo(args.servo) if args.servo is not None else DEFAULT_MASS_MODEL.servo
    design = _design(args)
    out: Path = args.output
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
        raise TumblebotError(f"-o {out} exists and is not an empty folder (pass --force to overwrite its package)")
    args.check_writable(out / "assembly.md", "-o")
    try:
        import build123d  # noqa: F401
        import ezdxf  # noqa: F401
    except ImportError:
        raise TumblebotError("tumblebot build needs the build extra: pip install 'tumblebot[build]' "
                             "(./dev.sh setup installs it)") from None
    from tumblebot.sim.hardware.package import build_package

    mass = replace(DEFAULT_MASS_MODEL, servo=spec)
    record = build_package(design, mass, out, progress=lambda what: print(f"build: {what}", file=sys.stderr))
    print(f"wrote the fabrication package for {design} with servo '{spec.name}' to {out}/")
    print(f"  mass {record['bom_kg'] * 1e3:.1f} g (parts list = mass model), 3D assembly "
          f"{record['cad']['mass'] * 1e3:.1f} g ({100 * record['cad_mass_error']:+.2f} %)")
    print(f"  start with {out / 'assembly.md'}")
    return 0


def add_command(sub: Any, number: Callable[[str], float], check_writable: Callable[[Path, str], None]) -> None:
    """Add ``build`` to the ``tumblebot`` parser. ``number`` parses a float argument and
    ``check_writable`` refuses an unwritable output path, as every other command does."""
    p = sub.add_parser(
        "build", help="write the fabrication package of a design: parts list, laser-cutter files, 3D model, guide",
        description="Write everything a lab needs to build a robot: bom.csv/bom.md (parts, sizes, masses; the total "
                    "is the mass model's m(w)), cut/*.dxf and cut/*.svg (laser-cutter files in mm, layers CUT and "
                    "ENGRAVE), robot.step, robot.glb and robot.png (the 3D assembly), wiring.svg/png, markers.csv "
                    "and assembly.md (assembly, wiring, flashing, servo neutral, motion capture).")
    p.add_argument("--design", metavar="X,Y,Z,L", default=None, help="the design in metres")
    p.add_argument("--storage", metavar="URL", default=None, help="take a study's optimum from this storage")
    p.add_argument("--study", metavar="NAME", default=None, help="the study (with --storage)")
    p.add_argument("--xi", type=number, default=None,
                   help="with --storage: the optimum for this energy weight ξ (default: the study's own objective)")
    p.add_argument("--servo", metavar="NAME", default=None,
                   help="a servo from the catalogue (default: the simulator's servo, 'thesis')")
    p.add_argument("-o", "--output", type=Path, required=True, help="folder to write the package into")
    p.add_argument("--force", action="store_true", help="write into a folder that is not empty")
    p.add_argument("--allow-out-of-bounds", action="store_true", help="accept designs outside the bounds")
    p.set_defaults(func=_build, check_writable=check_writable)
