"""The ``tumblebot`` command as a user types it."""

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest

from tumblebot.cli import main
from tumblebot.cliargs import positive_float

TABLE_3_1 = [((0.293, 0.117, 0.158, 0.218), 6.05), ((0.285, 0.117, 0.158, 0.218), 6.00),
             ((0.292, 0.129, 0.098, 0.136), 5.20), ((0.189, 0.104, 0.098, 0.152), 3.76)]


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tumblebot.cli", *args], capture_output=True, text=True,
                          timeout=300, check=False)


@pytest.mark.parametrize(("design", "e_thesis"), TABLE_3_1)
def test_that_power_json_reproduces_table_3_1_within_two_percent(design: tuple[float, ...], e_thesis: float,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["power", *map(str, design), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["e"] == pytest.approx(e_thesis, rel=0.02)
    assert 0.5 < out["mass"] < 0.8


def test_that_power_prints_a_readable_breakdown(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["power", "0.292", "0.129", "0.098", "0.136"]) == 0
    out = capsys.readouterr().out
    assert "flat half" in out and "tall half" in out and "W/m" in out


def test_that_power_reports_designs_that_cannot_tumble(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["power", "0.2", "0.2", "0.2", "0.07", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["can_tumble"] is False and out["e"] is None


@pytest.mark.parametrize(("args", "message"), [
    (["power", "0.2", "nan", "0.1", "0.1"], "y=nan is not finite"),
    (["power", "0.5", "0.12", "0.1", "0.1"], "x=0.5 m is outside its bound"),
    (["sim", "--task", "swim"], "unknown task 'swim'"),
    (["sim", "--gait", "moonwalk"], "unknown gait 'moonwalk'"),
    (["sim", "--design", "0.2,0.1"], "four comma-separated numbers"),
    (["sim", "--video", "out.mp4"], "must end in .gif"),
    (["urdf", "--design", "0.2,0.12,0.1,-1"], "l=-1.0 m must be positive"),
])
def test_that_bad_input_gives_one_error_line_and_exit_status_2(args: list[str], message: str) -> None:
    result = run_cli(*args)
    assert result.returncode == 2
    err_lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(err_lines) == 1, result.stderr
    assert message in err_lines[0]
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("text", ["-1e-3", "0", "nan", "inf", "-inf", "fast"])
def test_that_a_step_size_must_be_a_finite_number_above_zero(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        positive_float(text)
    assert positive_float("1e-4") == 1e-4


def test_that_a_negative_learning_rate_is_refused_before_any_work() -> None:
    result = run_cli("imitate", "--learning-rate", "-1")
    assert result.returncode == 2
    assert "--learning-rate: -1 must be a finite number above 0" in result.stderr
    assert "Traceback" not in result.stderr


def test_that_out_of_bounds_designs_pass_with_the_opt_in(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["power", "0.393", "0.117", "0.158", "0.218", "--allow-out-of-bounds", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["e"] > 6.05


def test_that_urdf_writes_a_file_pybullet_can_load(tmp_path: Path) -> None:
    import pybullet as p

    target = tmp_path / "robot.urdf"
    assert main(["urdf", "--design", "0.25,0.15,0.12,0.2", "-o", str(target)]) == 0
    client = p.connect(p.DIRECT)
    try:
        assert p.getNumJoints(p.loadURDF(str(target), physicsClientId=client), physicsClientId=client) == 2
    finally:
        p.disconnect(client)


def test_that_sim_writes_an_animation_in_which_the_robot_moves(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    from PIL import Image, ImageChops

    gif = tmp_path / "episode.gif"
    assert main(["sim", "--task", "distance-flat", "--gait", "forward", "--video", str(gif)]) == 0
    assert "final-state R" in capsys.readouterr().out
    with Image.open(gif) as im:
        assert getattr(im, "n_frames", 1) >= 200  # 10 frames per simulated second, 20 s
        im.seek(0)
        first = im.convert("RGB")
        im.seek(5)  # half a second in: the camera follows, the legs have turned
        later = im.convert("RGB")
        assert ImageChops.difference(first, later).getbbox() is not None


def test_that_demo_runs_every_task_and_prints_the_power_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo"]) == 0
    out = capsys.readouterr().out
    for task in ("nav-flat", "nav-terrain", "distance-flat", "incline"):
        assert task in out
    assert "Table 3.1" in out


@pytest.mark.parametrize("command", [[], ["power"], ["urdf"], ["sim"], ["train"], ["export"], ["evaluate"], ["demo"]])
def test_that_every_help_page_renders_regression_percent_in_help(command: list[str]) -> None:
    result = run_cli(*command, "--help")
    assert result.returncode == 0, result.stderr
    assert "usage: tumblebot" in result.stdout


@pytest.mark.slow
def test_that_the_main_job_prints_the_optimum_the_readme_quotes(tmp_path: Path) -> None:
    """``./dev.sh demo`` is seeded: its optimum must be the one README.md shows."""
    root = Path(__file__).resolve().parents[2]
    lines = (root / "dev.sh").read_text().splitlines()
    at = next(i for i, ln in enumerate(lines) if "optimize --tasks" in ln)
    words = (lines[at].split("optimize", 1)[1] + " " + lines[at + 1]).split()
    args = [w for w in words if w not in ("\\", '"$@"')]
    i = args.index("--storage")
    args[i + 1] = f"sqlite:///{tmp_path / 'demo.db'}"
    run = subprocess.run([sys.executable, "-m", "tumblebot.cli", "optimize", *args, "--quiet"], capture_output=True,
                         text=True, timeout=1800, check=False, stdin=subprocess.DEVNULL)
    assert run.returncode == 0, run.stderr
    readme = (root / "README.md").read_text()
    block = readme.split("## What the main job prints", 1)[1].split("```", 2)[1]
    shown = ("best robot", "  x =", "  e(w)", "  nav-flat", "  exact design")
    quoted = [ln.strip() for ln in block.splitlines() if ln.startswith(shown)]
    printed = [ln.strip() for ln in run.stdout.splitlines() if ln.startswith(shown)]
    assert printed == quoted and len(quoted) == 5, (printed, quoted)


def test_that_the_help_texts_name_every_task_and_no_other() -> None:
    from tumblebot.cli import TASK_NAMES
    from tumblebot.sim.world.tasks import TASKS

    assert tuple(TASKS) == TASK_NAMES


def test_that_sim_help_names_every_scripted_gait(capsys: pytest.CaptureFixture[str]) -> None:
    """The list is written out by hand (the parser must build without numpy on a Pi)."""
    from tumblebot.sim.control.gaits import GAITS

    with pytest.raises(SystemExit):
        main(["sim", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for name in GAITS:
        assert name in text, name
