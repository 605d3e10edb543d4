"""Ctrl-C while a command is still starting: a latch, not an exception.

Python's own SIGINT handler raises ``KeyboardInterrupt`` wherever the main thread happens
to be. While a command is still importing its libraries that can be inside a third-party
``try``/``except`` around an import, or inside a C extension's initialisation, where the
exception is turned into something else or swallowed, and the Ctrl-C is lost: the
command then runs to its end as if nobody had asked it to stop.

:func:`hold` replaces the handler with one that only records the signal. A command that
stops at safe points of its own (``optimize``'s :class:`~tumblebot.sim.optimize.StopFlag`)
asks :func:`take` when it installs its own handler; every other command calls
:func:`release` once its arguments are parsed, which restores Python's handler and raises
the ``KeyboardInterrupt`` of a Ctrl-C that arrived meanwhile, at that one known point.

Standard library only: ``tumblebot.cli`` imports this before anything heavy.
"""

from __future__ import annotations

import signal
import threading
from types import FrameType

_requested = threading.Event()


def _latch(signum: int, frame: FrameType | None) -> None:
    _requested.set()


def hold() -> None:
    """Record Ctrl-C from now on instead of raising (main thread, and only where Ctrl-C
    is at Python's default: a process started with SIGINT ignored keeps ignoring it)."""
    if threading.current_thread() is threading.main_thread() \
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _latch)


def held() -> bool:
    """Whether :func:`hold`'s latch is the SIGINT handler now."""
    return signal.getsignal(signal.SIGINT) is _latch


def take() -> bool:
    """Whether a Ctrl-C arrived while the latch was held; it counts as handled from now on
    (the caller's own stop flag carries it)."""
    was = _requested.is_set()
    _requested.clear()
    return was


def release() -> None:
    """Give Ctrl-C back to Python; raise ``KeyboardInterrupt`` here if one was recorded."""
    if held():
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if take():
        raise KeyboardInterrupt
