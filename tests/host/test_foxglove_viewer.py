"""Foxglove Studio itself opens a trial log, and reports no problem reading it.

The viewer is Foxglove Studio's ``@foxglove/studio-base`` bundle (npm, pinned in
``docs/screenshot/package.json``) in Debian's headless Chromium, driven by
``docs/screenshot/shoot.mjs``; ``./dev.sh test`` installs both. Reading our logs in the
real viewer first found two schemas it refused (a ``["number", "null"]`` type, an object
without fields) that our own schema checks had passed.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from tests.host.test_foxglove import _trial_log

VIEWER = Path(__file__).parents[2] / "docs" / "screenshot"


@pytest.mark.slow
def test_that_foxglove_studio_opens_a_trial_log_without_problems(tmp_path: Path) -> None:
    node = shutil.which("node")
    installed = (VIEWER / "node_modules" / "@foxglove" / "studio-base").is_dir() and Path("/usr/bin/chromium").exists()
    assert node and installed, \
        "the viewer is not installed: ./dev.sh test installs Node.js, Chromium and docs/screenshot's npm packages"
    log, shot = tmp_path / "trial.mcap", tmp_path / "trial.png"
    _trial_log(log)
    run = subprocess.run([node, "shoot.mjs", str(log), str(shot)], cwd=VIEWER, capture_output=True, text=True,
                         timeout=900, check=False)
    assert run.returncode == 0, run.stdout + run.stderr  # names each problem Foxglove reported
    assert shot.stat().st_size > 20_000  # a drawn window, not a blank page
