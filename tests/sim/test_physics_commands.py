"""``--physics`` on the commands that run episodes: the profile reaches the episodes, is
recorded, and a policy or study made under one world is refused under another; records
made before profiles still load as the thesis's world."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tumblebot.cli import main
from tumblebot.sim.optimize import Objective, Recipe, StudyConfig
from tumblebot.sim.world.physics import THESIS, PhysicsProfile
from tumblebot.training.config import TrainConfig, TrainingError

XI3 = "0.292,0.129,0.098,0.136"


@pytest.fixture
def slow_servo(tmp_path: Path) -> Path:
    path = tmp_path / "slow.json"
    PhysicsProfile(name="slow", free_speed=2.0, friction=0.6).write(path)
    return path


def test_that_evaluate_runs_and_records_the_profile(slow_servo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = ["evaluate", "--task", "nav-flat", "--design", XI3, "--gait", "goto", "--episodes", "4", "--json"]
    assert main(base) == 0
    thesis = json.loads(capsys.readouterr().out)
    assert main([*base, "--physics", str(slow_servo)]) == 0
    slow = json.loads(capsys.readouterr().out)
    assert thesis["physics"]["digest"] == THESIS.digest()
    assert slow["physics"]["digest"] == PhysicsProfile.load(str(slow_servo)).digest()
    assert slow["physics"]["free_speed"] == 2.0 and slow["mean_R"] != thesis["mean_R"]


def test_that_the_shorthands_apply_on_top_of_the_profile(slow_servo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--task", "nav-flat", "--design", XI3, "--gait", "goto", "--episodes", "2", "--json",
                 "--physics", str(slow_servo), "--stall-torque", "1.5"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["physics"]["free_speed"], out["physics"]["stall_torque"], out["physics"]["friction"]) == (2.0, 1.5, 0.6)


def test_that_a_policy_trained_under_the_thesis_world_is_refused_under_another(
        slow_servo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--task", "nav-flat", "--design", XI3, "--episodes", "2", "--physics",
                 str(slow_servo)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "was trained under the dc servo, stall torque 0.582 N·m, not the slow:" in err[0]


def test_that_sim_runs_the_profile(slow_servo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "--task", "nav-flat", "--design", XI3, "--gait", "forward"]) == 0
    thesis = capsys.readouterr().out
    assert main(["sim", "--task", "nav-flat", "--design", XI3, "--gait", "forward", "--physics", str(slow_servo)]) == 0
    slow = capsys.readouterr().out
    assert "slow: dc servo, free speed 2 rad/s" in slow
    assert slow.splitlines()[-1] != thesis.splitlines()[-1]  # the last step's position differs


def test_that_a_bad_profile_is_one_error_line_for_every_command(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"friction": -1}')
    for argv in (["sim", "--task", "nav-flat", "--design", XI3],
                 ["evaluate", "--task", "nav-flat", "--design", XI3, "--gait", "goto"],
                 ["optimize", "--tasks", "nav-flat", "--trials", "1", "--batch", "2", "--storage",
                  f"sqlite:///{tmp_path / 's.db'}"]):
        assert main([*argv, "--physics", str(bad)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "friction -1 must be a number" in err[0], (argv, err)
    assert not (tmp_path / "s.db").exists()


def test_that_a_study_keeps_its_profile_and_old_studies_resume_as_the_thesis_world() -> None:
    objective, recipe = Objective({"nav-flat": 1.0}, 3.0), Recipe.make("standard", 4, 8)
    lab = PhysicsProfile(name="lab", free_speed=3.0, friction=0.6)
    config = StudyConfig.of(objective, recipe, 0, {}, "goto", lab)
    assert config.physics is not None and config.profile().same_as(lab)
    assert any(line.startswith("physics:") for line in config.differences(StudyConfig.of(objective, recipe, 0, {},
                                                                                          "goto", THESIS)))
    renamed = PhysicsProfile(**{**lab.to_json(), "name": "lab-copy", "latency": lab.latency})
    assert config.differences(StudyConfig.of(objective, recipe, 0, {}, "goto", renamed)) == []
    old = StudyConfig.of(objective, recipe, 0, {}, "goto")
    assert old.physics is None and old.profile() is THESIS  # stored as before profiles existed
    strong = StudyConfig.of(objective, recipe, 0, {}, "goto", PhysicsProfile.of("velocity", 10.0))
    assert strong.physics is None and (strong.motor_model, strong.stall_torque) == ("velocity", 10.0)


def test_that_a_training_config_carries_the_profile_and_refuses_a_bad_one() -> None:
    lab = PhysicsProfile(name="lab", free_speed=3.0, latency=(0.0, 0.1))
    config = TrainConfig(**lab.as_fields())
    assert config.profile().same_as(lab) and config.randomization().latency == (0.0, 0.1)
    assert TrainConfig().profile() is THESIS
    with pytest.raises(TrainingError, match="free_speed"):
        TrainConfig(physics={**lab.to_json(), "free_speed": -1.0})
