"""Helpers the test suites share."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Mapping


def tb(*args: str, timeout: float = 1200, env: Mapping[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """Run ``tumblebot ARGS…`` as a user would (its own process, no stdin); ``timeout`` is a
    generous bound, never a measure of speed."""
    return subprocess.run([sys.executable, "-m", "tumblebot.cli", *args], capture_output=True, text=True,
                          timeout=timeout, check=False, stdin=subprocess.DEVNULL,
                          env=None if env is None else {**os.environ, **env})
