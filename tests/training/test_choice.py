"""The goto choice: a sweep's paired differences smoothed over the design space, and the
DAgger teacher of a ``dual`` policy that follows it."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from tumblebot.cli import main
from tumblebot.defaults import XI3_ROBOT
from tumblebot.sim.control.goto import GotoConfig
from tumblebot.sim.control.policy import DUAL_GOTO, RESIDUAL_GOTO
from tumblebot.sim.world.design import Design, tumbling_designs
from tumblebot.sim.world.physics import THESIS
from tumblebot.training.choice import SEEDING, GotoChoice, reach, read_sweep, sweep
from tumblebot.training.config import TrainingError
from tumblebot.training.imitation import choice_teacher


def _records(noise: float = 0.0, seed: int = 0) -> list[dict[str, object]]:
    """A made-up sweep: the second setting gains 0.03 where l/r > 1.4, loses 0.03 elsewhere."""
    rng = np.random.default_rng(seed)
    return [{"design": list(d.as_tuple()),
             "difference": (0.03 if d.l / d.pivot_radius > 1.4 else -0.03) + noise * float(rng.normal())}
            for d in tumbling_designs(200, seed=seed)]


def test_that_the_sweep_draws_only_designs_that_can_tumble() -> None:
    designs = tumbling_designs(50, seed=4)
    assert len(designs) == 50 and all(d.can_tumble and d.in_bounds() for d in designs)
    assert designs == tumbling_designs(50, seed=4)


def test_that_the_choice_recovers_where_the_second_setting_is_ahead_through_noise() -> None:
    records = _records(noise=0.03)
    for record in records:
        record["se"] = 0.03
    choice = GotoChoice.fit(records)
    assert 1.3 < choice.threshold < 1.55  # the true change-over is 1.4; the rule leans high
    held_out = tumbling_designs(300, seed=9)
    truth = np.array([reach(d.as_tuple())[0] > 1.4 for d in held_out])
    predicted = np.array([choice.prefers_dual(d.as_tuple()) for d in held_out])
    assert (predicted == truth).mean() > 0.85


def test_that_the_one_standard_error_rule_takes_the_highest_threshold_within_noise_of_the_best() -> None:
    designs = tumbling_designs(400, seed=5)
    records = [{"design": list(d.as_tuple()), "se": 0.001,
                "difference": 0.03 if reach(d.as_tuple())[0] > 1.5 else (0.0 if reach(d.as_tuple())[0] > 1.2
                                                                         else -0.05)}
               for d in designs]
    choice = GotoChoice.fit(records)
    # between 1.2 and 1.5 every threshold gains the same, and the rule takes the highest of them
    assert choice.threshold > 1.45
    assert all(choice.prefers_dual(d.as_tuple()) for d in designs if reach(d.as_tuple())[0] > 1.5)


def test_that_a_choice_file_round_trips_and_a_bad_one_is_one_error(tmp_path: Path) -> None:
    choice = GotoChoice.fit(_records())
    path = tmp_path / "choice.json"
    path.write_text(choice.to_json())
    again = GotoChoice.load(path)
    assert again.threshold == choice.threshold
    np.testing.assert_array_equal(again.designs, choice.designs)
    data = json.loads(path.read_text())
    data["second"] = {**DUAL_GOTO, "spin_steps_left": 5}  # made for other settings than the pinned ones
    path.write_text(json.dumps(data))
    with pytest.raises(TrainingError, match="pinned goto settings"):
        GotoChoice.load(path)
    path.write_text("{")
    with pytest.raises(TrainingError, match="goto choice"):
        GotoChoice.load(path)


def test_that_a_bad_sweep_line_is_named(tmp_path: Path) -> None:
    path = tmp_path / "sweep.jsonl"
    path.write_text(json.dumps({"design": [0.2, 0.12, 0.1, 0.15], "difference": 0.01}) + "\n{\"design\": 3}\n")
    with pytest.raises(TrainingError, match=r"sweep.jsonl:2"):
        read_sweep(path)


def test_that_the_teacher_follows_the_setting_the_choice_prefers() -> None:
    teacher = choice_teacher(GotoChoice.fit(_records()))
    long_legs, short_legs = np.array([0.25, 0.12, 0.10, 0.20]), np.array([0.25, 0.20, 0.18, 0.15])
    assert teacher(long_legs) == GotoConfig(**DUAL_GOTO)
    assert teacher(short_legs) == GotoConfig(**RESIDUAL_GOTO)


@pytest.mark.slow
def test_that_the_sweep_pairs_both_settings_on_the_same_episodes() -> None:
    design = Design(*XI3_ROBOT)
    records = list(sweep([design], episodes=4, seed=0, workers=1))
    assert len(records) == 1 and records[0]["episodes"] == 4
    r = records[0]
    assert r["difference"] == pytest.approx(r["dual"] - r["goto"])
    assert next(sweep([design], episodes=4, seed=0, workers=1))["goto"] == r["goto"]  # reproducible


def test_that_imitate_refuses_a_dual_student_without_a_choice_before_writing(tmp_path: Path,
                                                                           capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    assert main(["imitate", "--run-dir", str(run), "--observation", "dual", "--iterations", "1"]) == 2
    assert "needs --choice" in capsys.readouterr().err
    assert not run.exists()


def test_that_a_sweep_file_of_another_sweep_is_not_continued(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sweep.jsonl"
    first = tumbling_designs(3, seed=3)[0]
    line = {"index": 0, "design": list(first.as_tuple()), "episodes": 48, "seed": 3, "seeding": SEEDING,
            "physics": THESIS.digest(), "difference": 0.0, "se": 0.01}
    for other, message in (({"seed": 4}, "holds another sweep"),
                           ({"physics": "0" * 16}, "holds another sweep"),
                           ({"seeding": None}, "earlier tumblebot")):
        out.write_text(json.dumps({**line, **other}) + "\n")
        before = out.read_text()
        assert main(["choice", "sweep", "--designs", "3", "--episodes", "48", "--seed", "3", "--out", str(out)]) == 2
        assert message in capsys.readouterr().err
        assert out.read_text() == before


# --------------------------------------------------------------------------- dual-plan
def test_that_the_dual_plan_layouts_gotos_are_plan_and_plan_with_the_thesis_robots_turning() -> None:
    from tumblebot.sim.control.goto import NAVIGATORS
    from tumblebot.sim.observation import DUAL_LAYOUTS, GOTO_SETTINGS, LAYOUTS, PLAN_DUAL_GOTO, PLAN_GOTO

    assert DUAL_LAYOUTS == ("dual", "dual-plan") and LAYOUTS["dual-plan"] == LAYOUTS["dual"]
    assert GotoConfig(**PLAN_GOTO) == NAVIGATORS["plan"]  # pinned: plan's defaults may move, the layout may not
    assert GotoConfig(**PLAN_DUAL_GOTO) == GotoConfig(memory=0.25, turn_tolerance=0.3, spin_steps_left=4)
    assert GOTO_SETTINGS["dual-plan"] == (PLAN_GOTO, PLAN_DUAL_GOTO)


def test_that_a_dual_plan_choice_teaches_plans_two_settings_and_says_so_in_its_file(tmp_path: Path) -> None:
    from tumblebot.sim.observation import PLAN_DUAL_GOTO, PLAN_GOTO

    records = [{**r, "layout": "dual-plan"} for r in _records()]
    choice = GotoChoice.fit(records)
    assert choice.layout == "dual-plan" and choice.settings == (PLAN_GOTO, PLAN_DUAL_GOTO)
    teacher = choice_teacher(choice)
    assert teacher(np.array([0.25, 0.12, 0.10, 0.20])) == GotoConfig(**PLAN_DUAL_GOTO)
    assert teacher(np.array([0.25, 0.20, 0.18, 0.15])) == GotoConfig(**PLAN_GOTO)
    path = tmp_path / "choice.json"
    path.write_text(choice.to_json())
    assert json.loads(path.read_text())["layout"] == "dual-plan" and GotoChoice.load(path).layout == "dual-plan"
    with pytest.raises(TrainingError, match="mixes the goto settings of dual, dual-plan"):
        GotoChoice.fit([*records[:10], *_records()[10:]])


def test_that_imitate_refuses_a_choice_fitted_for_the_other_layout_before_writing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "choice.json"
    path.write_text(GotoChoice.fit(_records()).to_json())  # a dual choice (sweeps without a layout were dual)
    run = tmp_path / "run"
    assert main(["imitate", "--run-dir", str(run), "--observation", "dual-plan", "--iterations", "1",
                 "--choice", str(path)]) == 2
    assert "fitted for the dual layout's gotos, not dual-plan's" in capsys.readouterr().err
    assert not run.exists()


def test_that_a_sweep_of_the_other_layout_is_not_continued(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sweep.jsonl"
    first = tumbling_designs(3, seed=3)[0]
    out.write_text(json.dumps({"index": 0, "design": list(first.as_tuple()), "episodes": 48, "seed": 3,
                               "seeding": SEEDING, "physics": THESIS.digest(), "difference": 0.0, "se": 0.01}) + "\n")
    before = out.read_text()
    assert main(["choice", "sweep", "--designs", "3", "--episodes", "48", "--seed", "3", "--layout", "dual-plan",
                 "--out", str(out)]) == 2
    assert "--layout dual-plan" in capsys.readouterr().err and out.read_text() == before


# --------------------------------------------------------------------------- nav-terrain
def test_that_a_terrain_sweep_drives_terrain_episodes_the_way_an_evaluation_does() -> None:
    from tumblebot.sim.control.drivers import Driver
    from tumblebot.sim.evaluation.runner import EpisodeRunner

    design = Design(*XI3_ROBOT)
    record = next(sweep([design], episodes=3, seed=0, workers=1, layout="dual-plan", task="nav-terrain"))
    assert record["task"] == "nav-terrain"
    runner = EpisodeRunner({"nav-terrain": Driver.of_gait("plan")}, workers=1)
    try:
        plan = runner.run(design, ["nav-terrain"], 0, 3, 0)["nav-terrain"]
    finally:
        runner.close()
    assert record["goto"] == pytest.approx(float(plan.mean()), abs=1e-12)  # the first setting is plan itself
    flat = next(sweep([design], episodes=3, seed=0, workers=1, layout="dual-plan"))
    assert flat["task"] == "nav-flat" and flat["goto"] != record["goto"]


def test_that_a_choice_says_which_task_it_was_swept_on_and_never_mixes_two(tmp_path: Path) -> None:
    records = [{**r, "layout": "dual-plan", "task": "nav-terrain"} for r in _records()]
    choice = GotoChoice.fit(records)
    assert choice.task == "nav-terrain" and "nav-terrain designs" in choice.summary()
    losing = GotoChoice.fit([{**r, "difference": -0.03, "se": 0.01} for r in records])  # as on terrain
    assert not any(losing.prefers_dual(d.as_tuple()) for d in tumbling_designs(200, seed=0))
    assert "0 of 200 swept nav-terrain designs, mean paired difference there none, below -0.0300" in losing.summary()
    path = tmp_path / "choice.json"
    path.write_text(choice.to_json())
    assert GotoChoice.load(path).task == "nav-terrain"
    assert GotoChoice.fit(_records()).task == "nav-flat"  # sweeps before the task was recorded were of nav-flat
    with pytest.raises(TrainingError, match="mixes the tasks nav-flat, nav-terrain"):
        GotoChoice.fit([*records[:10], *({**r, "layout": "dual-plan"} for r in _records()[10:])])
    path.write_text(choice.to_json().replace('"nav-terrain"', '"incline"'))
    with pytest.raises(TrainingError, match="task 'incline' is not one of"):
        GotoChoice.load(path)


def test_that_a_sweep_of_the_other_task_is_not_continued(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sweep.jsonl"
    first = tumbling_designs(3, seed=3)[0]
    out.write_text(json.dumps({"index": 0, "design": list(first.as_tuple()), "episodes": 48, "seed": 3,
                               "seeding": SEEDING, "physics": THESIS.digest(), "layout": "dual-plan",
                               "difference": 0.0, "se": 0.01}) + "\n")  # no task: a nav-flat sweep
    before = out.read_text()
    assert main(["choice", "sweep", "--designs", "3", "--episodes", "48", "--seed", "3", "--layout", "dual-plan",
                 "--task", "nav-terrain", "--out", str(out)]) == 2
    assert "--task nav-terrain" in capsys.readouterr().err and out.read_text() == before
    assert main(["choice", "sweep", "--designs", "3", "--task", "incline", "--out", str(out)]) == 2
    assert "not navigation" in capsys.readouterr().err and out.read_text() == before


def test_that_a_plan_student_names_its_teacher_in_its_log_and_a_plan_sweep_its_first_setting(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sweep.jsonl"
    assert main(["choice", "sweep", "--designs", "1", "--episodes", "2", "--seed", "3", "--layout", "dual-plan",
                 "--workers", "1", "--out", str(out)]) == 0
    assert re.search(r": plan -?\d\.\d{3}, second setting [+-]\d\.\d{3} ± ", capsys.readouterr().out)
    path = tmp_path / "choice.json"
    path.write_text(GotoChoice.fit([{**r, "layout": "dual-plan"} for r in _records()]).to_json())
    run = tmp_path / "run"
    assert main(["imitate", "--run-dir", str(run), "--observation", "dual-plan", "--choice", str(path),
                 "--iterations", "2", "--episodes", "2", "--updates", "2", "--envs", "1", "--net-arch", "8,8"]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("imitating plan under the setting") and "agreement with plan" in printed
    rows = [line.split(",") for line in (run / "imitation.csv").read_text().splitlines()]
    assert [r[1] for r in rows[1:]] == ["plan", "student"]
