"""Importing PyBullet quietly.

PyBullet writes ``pybullet build time: …`` through C stdio when first imported, and it
surfaces at exit, in the middle of a command's output. :func:`pybullet` imports the
module with file descriptors 1 and 2 pointed at /dev/null and flushes C stdio before
restoring them, so the banner goes nowhere. Returns the module.
"""

from __future__ import annotations

import os
import sys
from types import ModuleType


def _flush_c_stdio() -> None:
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # not a POSIX libc: nothing buffered to worry about
        pass


def pybullet() -> ModuleType:
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        import pybullet as p

        _flush_c_stdio()
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)
    module: ModuleType = p
    return module
