"""What a newcomer meets first: messages a new user reads on a fresh clone, each named after
the fault it fixes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.calibration_logs import write_set
from tests.helpers import tb, tb_ok
from tumblebot.sim.world.physics import THESIS

ROOT = Path(__file__).resolve().parents[2]




def _agent_only_python(tmp_path: Path, code: str) -> subprocess.CompletedProcess[str]:
    """Run ``code`` in an interpreter that sees tumblebot and pyserial only (``-S``: no
    site-packages), as on a Raspberry Pi with the ``agent`` extra."""
    import serial

    import tumblebot

    shelf = tmp_path / "agent-only"
    shelf.mkdir()
    (shelf / "serial").symlink_to(Path(serial.__file__).parent)
    package_root = Path(tumblebot.__file__).resolve().parent.parent  # the editable tree or src/
    editable = next((p for p in (ROOT / "build").glob("__editable__.*")), None)
    paths = [str(shelf), str(editable if editable is not None else package_root)]
    prelude = f"import sys; sys.path[:0] = {paths!r}; "
    return subprocess.run([sys.executable, "-S", "-c", prelude + code], capture_output=True, text=True, timeout=120,
                          check=False, stdin=subprocess.DEVNULL)


@pytest.mark.parametrize("argv", [["power", "0.2", "0.12", "0.1", "0.14"], ["evaluate", "--task", "nav-flat",
                                  "--design", "0.292,0.129,0.098,0.136", "--episodes", "1", "--seed", "0"],
                                  ["trim", "--agent", "127.0.0.1:47800", "--key", "agent.key"]])
def test_that_a_pi_with_only_the_agent_extra_is_told_which_extra_to_install_regression_numpy_traceback(
        tmp_path: Path, argv: list[str]) -> None:
    run = _agent_only_python(tmp_path, f"from tumblebot.cli import main; sys.exit(main({argv!r}))")
    assert "No module named 'numpy'" not in run.stderr or "Traceback" not in run.stderr
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "needs the 'sim' extra" in lines[0] and "pip install 'tumblebot[sim]'" in lines[0]


def test_that_the_agent_itself_runs_with_only_the_agent_extra(tmp_path: Path) -> None:
    run = _agent_only_python(tmp_path, "from tumblebot.pi_agent.agent import main; sys.exit(main(['--help']))")
    assert run.returncode == 0, run.stderr
    assert "usage:" in run.stdout


@pytest.mark.parametrize("argv", [["optimize", "--trials", "zero"], ["evaluate", "--task"], ["bogus"],
                                  ["trial", "run", "--out"], ["power", "1"]])
def test_that_argparse_errors_are_the_usage_then_one_error_line_as_documented_regression_unannounced_usage_block(
        argv: list[str]) -> None:
    run = tb(*argv)
    assert run.returncode == 2 and run.stdout == ""
    lines = run.stderr.rstrip("\n").splitlines()
    assert lines[0].startswith("usage: tumblebot")
    errors = [ln for ln in lines if ": error: " in ln]
    assert len(errors) == 1 and errors[0] == lines[-1], lines
    assert "Traceback" not in run.stderr
    documented = (ROOT / "docs" / "reference" / "cli.md").read_text()
    assert "command's usage, then one `tumblebot …: error: …` line" in " ".join(documented.split())


@pytest.mark.parametrize(("task", "wording"), [("incline", "median final distance from the start (the origin)"),
                                               ("nav-flat", "median final distance to the goal (the origin)")])
def test_that_evaluate_names_the_distance_it_prints_regression_incline_distance_to_the_origin(
        task: str, wording: str) -> None:
    run = tb_ok("evaluate", "--task", task, "--design", "0.292,0.129,0.098,0.136", "--episodes", "2", "--seed", "0",
                "--gait", "forward")
    assert wording in run.stdout


def test_that_one_trial_gets_no_confidence_interval_regression_ci_of_a_single_value(tmp_path: Path) -> None:
    folder = write_set(tmp_path / "one", THESIS, 1)
    run = tb_ok("trial", "analyze", str(folder), "--baseline-mean", "0.433", "--baseline-sd", "0.25",
                "--baseline-n", "100")
    assert "no CI from one trial" in run.stdout and "no t-test" in run.stdout
    assert "(0." not in run.stdout.split("mean setpoint error", 1)[1].split("\n", 1)[0].replace("(no CI", "")
    result = json.loads(tb("trial", "analyze", str(folder), "--json").stdout)
    assert result["ci95"] is None and result["per_point"][0]["ci95"] is None


@pytest.mark.parametrize(("argv", "shown"), [
    (["export", "--help"], ["(default 240; 0: skip it)", "(default 0)", "(default 1)"]),
    (["twin", "check", "--help"], ["the trial-set folder a twin run wrote"]),
    (["optimize", "--help"], ["efficient recipe", "standard and thesis recipes"]),
    (["train", "--help"], ["thesis,context,memory,residual,dual"]),
])
def test_that_help_pages_show_defaults_choices_and_argument_help_regression_silent_help(
        argv: list[str], shown: list[str]) -> None:
    import os

    run = subprocess.run([sys.executable, "-m", "tumblebot.cli", *argv], capture_output=True, text=True,
                         timeout=120, check=False, env={**os.environ, "COLUMNS": "400"})
    assert run.returncode == 0, run.stderr
    text = " ".join(run.stdout.split())
    for words in shown:
        assert words in text, (words, text[:3000])
