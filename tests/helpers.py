"""Helpers the test suites share."""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from types import ModuleType


def tb(*args: str, timeout: float = 1200, env: Mapping[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """Run ``tumblebot ARGS…`` as a user would (its own process, no stdin); ``timeout`` is a
    generous bound, never a measure of speed."""
    return subprocess.run([sys.executable, "-m", "tumblebot.cli", *args], capture_output=True, text=True,
                          timeout=timeout, check=False, stdin=subprocess.DEVNULL,
                          env=None if env is None else {**os.environ, **env})


def tb_ok(*args: str, timeout: float = 1200, env: Mapping[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """:func:`tb`, which must succeed (its stderr is the failure's message)."""
    run = tb(*args, timeout=timeout, env=env)
    assert run.returncode == 0, run.stderr
    return run


def interruptible() -> None:
    """``preexec_fn`` for a child a test will Ctrl-C: SIGINT as in a terminal. A runner that
    starts the tests in the background (``nohup``, ``&``) has SIGINT ignored, and a child
    inherits that, so the Ctrl-C the test sends would never arrive."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def load_script(path: Path, name: str) -> ModuleType:
    """The Python file ``path`` (a report script, a docs hook: not part of the package)
    imported as module ``name`` and registered in ``sys.modules`` (its dataclasses and
    worker processes look themselves up there)."""
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
