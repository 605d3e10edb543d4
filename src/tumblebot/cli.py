"""The ``tumblebot`` command: its parser, and the dispatch of each subcommand.

Each command's options and handler live in the package it belongs to (``sim/commands.py``,
``training/commands.py``, ``sim/optimize_command.py``, ``sim/report_command.py``,
``sim/hardware/commands.py``, ``sim/physics_command.py``, ``host/commands.py``); their shared
argument types are in :mod:`tumblebot.cliargs`. Any :class:`~tumblebot.errors.TumblebotError`
becomes one ``tumblebot: error: …`` line and exit status 2, never a traceback; a package
an extra did not install becomes one line naming the extra. Heavy imports happen inside
the handlers, so ``tumblebot --help`` stays fast.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Sequence

from tumblebot import interrupts
from tumblebot.cliargs import check_writable, number, positive_int
from tumblebot.errors import TumblebotError

__all__ = ["TASK_NAMES", "build_parser", "main", "missing_extra"]  # noqa: F822 (TASK_NAMES: __getattr__)


def __getattr__(name: str) -> object:
    """``TASK_NAMES``, imported when asked for: the simulator's package (Gymnasium, NumPy)
    takes about 0.3 s to import, and until :func:`main` holds Ctrl-C
    (:mod:`tumblebot.interrupts`), a Ctrl-C raised inside an import can be lost."""
    if name == "TASK_NAMES":
        from tumblebot.sim.world.tasks import TASK_NAMES

        return TASK_NAMES
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def build_parser() -> argparse.ArgumentParser:
    from tumblebot import __version__
    from tumblebot.host.commands import add_commands as add_host_commands
    from tumblebot.sim.commands import add_commands as add_sim_commands
    from tumblebot.sim.commands import add_demo_command
    from tumblebot.sim.hardware.commands import add_command as add_build_command
    from tumblebot.sim.optimize_command import add_command as add_optimize_command
    from tumblebot.sim.physics_command import add_command as add_physics_command
    from tumblebot.sim.report_command import add_command as add_report_command
    from tumblebot.training.commands import add_commands as add_training_commands

    parser = argparse.ArgumentParser(
        prog="tumblebot",
        description="Simulate, train, optimise and deploy two-legged tumbling robots.",
    )
    parser.add_argument("--version", action="version", version=f"tumblebot {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    add_sim_commands(sub)
    add_training_commands(sub)
    add_optimize_command(sub)
    add_report_command(sub)
    add_build_command(sub, number, check_writable)
    add_host_commands(sub, positive_int, check_writable)
    add_physics_command(sub)
    add_demo_command(sub)
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
