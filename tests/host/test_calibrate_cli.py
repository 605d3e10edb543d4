"""``tumblebot calibrate`` from the command line: bad input is one line and writes nothing;
a fit writes the profile and its picture; Ctrl-C keeps the simulations and the same command
resumes."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.calibration_logs import write_set
from tests.helpers import interruptible, tb, tb_ok
from tumblebot.host.calibrate import cache_path
from tumblebot.sim.calibration import MIN_DESIGN_POINTS, Settings
from tumblebot.sim.world.physics import PhysicsProfile

HIDDEN = PhysicsProfile.from_json({"name": "hidden", "free_speed": 4.4, "stall_torque": 0.9, "friction": 0.6})
SMALL = ("--budget", str(MIN_DESIGN_POINTS), "--workers", "2")




@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_set(tmp_path_factory.mktemp("calibrate") / "set", HIDDEN, trials=5)


def refused(result: subprocess.CompletedProcess[str], *words: str) -> None:
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and lines[0].startswith("tumblebot: error:"), result.stderr
    for word in words:
        assert word in lines[0], lines[0]


def test_bad_input_is_one_line_and_writes_nothing(tmp_path: Path, logs: Path) -> None:
    out = tmp_path / "out" / "lab.json"
    out.parent.mkdir()
    empty = tmp_path / "empty"
    empty.mkdir()
    refused(tb("calibrate", str(empty), "-o", str(out)), "no trial logs")
    refused(tb("calibrate", str(tmp_path / "nowhere"), "-o", str(out)), "no such folder")
    refused(tb("calibrate", str(logs), "-o", str(out), "--design", "0.3,0.1,0.1,0.15"), "design")
    bad = tmp_path / "bad.json"
    bad.write_text('{"free_speed": 3.0, "gearing": 2}')
    refused(tb("calibrate", str(logs), "-o", str(out), "--prior", str(bad)), "unknown key", "gearing")
    bad.write_text('{"free_speed": NaN}')
    refused(tb("calibrate", str(logs), "-o", str(out), "--prior", str(bad)), "free_speed")
    refused(tb("calibrate", str(logs), "-o", str(tmp_path / "lab.txt")), ".json")
    refused(tb("calibrate", str(logs), "-o", str(out), "--budget", "3"), "design points")
    corrupt = tmp_path / "corrupt"
    shutil.copytree(logs, corrupt)
    victim = corrupt / "trial-0002.mcap"
    victim.write_bytes(victim.read_bytes()[: len(victim.read_bytes()) // 2])  # cut short
    refused(tb("calibrate", str(logs), str(corrupt), "-o", str(out)), "trial-0002.mcap", "not a complete")
    victim.write_bytes(b"not an mcap file at all")
    refused(tb("calibrate", str(corrupt), "-o", str(out)), "trial-0002.mcap")
    assert list(out.parent.iterdir()) == []


@pytest.mark.slow
def test_a_calibration_writes_the_profile_and_its_picture_and_resumes_after_ctrl_c(tmp_path: Path, logs: Path) -> None:
    out = tmp_path / "lab.json"
    cmd = [sys.executable, "-m", "tumblebot.cli", "calibrate", str(logs), "-o", str(out), *SMALL, "--json"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            stdin=subprocess.DEVNULL, preexec_fn=interruptible)
    deadline = time.monotonic() + 300
    while not (cache_path(out).is_file() and len(cache_path(out).read_text().splitlines()) >= 5):
        assert proc.poll() is None and time.monotonic() < deadline, "no simulation was cached"
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "resume" in err and not out.exists() and not (tmp_path / "calibration.png").exists()
    kept = len(cache_path(out).read_text().splitlines())
    assert kept >= 5

    done = tb_ok(*cmd[3:])
    result = json.loads(done.stdout)
    assert set(result) >= {"parameters", "fit"}
    for name, p in result["parameters"].items():
        assert set(p) >= {"value", "low", "high", "identifiable"}, name
        assert p["low"] <= p["value"] <= p["high"]
    for name in ("free_speed", "stall_torque", "friction"):  # what it calls identified holds the truth
        p = result["parameters"][name]
        assert not p["identifiable"] or p["low"] <= getattr(HIDDEN, name) <= p["high"], (name, p)
    speed = result["parameters"]["free_speed"]
    settings = Settings(design_points=MIN_DESIGN_POINTS)
    searched = settings.search_simulations() if result["fit"]["kept_values_checked"] else 0
    # the prior 8 times, the fitted profile 16 times, the rounds' points
    assert settings.simulations() == 3 * 8 + sum(settings.rounds())
    assert result["fit"]["simulated_sets"] == settings.simulations() + searched - kept  # nothing twice
    written = PhysicsProfile.load(str(out))
    assert written.name == "lab" and written.free_speed == speed["value"]
    assert (tmp_path / "calibration.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not cache_path(out).exists()  # the simulations are removed with the profile written
    shown = tb("physics", "show", str(out))
    assert shown.returncode == 0 and "lab" in shown.stdout
