"""The goto choice: a sweep's paired differences smoothed over the design space, and the
DAgger teacher of a ``dual`` policy that follows it."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

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
             "difference": (0.03 if d.reach > 1.4 else -0.03) + noise * float(rng.normal())}
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
    data["settings"][1] = {**DUAL_GOTO, "spin_steps_left": 5}  # made for other settings than the pinned ones
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
    from tumblebot.sim.observation import CHOICE_LAYOUTS, GOTO_SETTINGS, LAYOUTS, PLAN_DUAL_GOTO, PLAN_GOTO

    assert CHOICE_LAYOUTS == ("dual", "dual-plan", "tri-plan") and LAYOUTS["dual-plan"] == LAYOUTS["dual"]
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
    assert ("0 of 200 swept nav-terrain designs, mean paired difference there none, elsewhere -0.0300"
            in losing.summary())
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
    assert re.search(r": plan -?\d\.\d{3}, setting 2 [+-]\d\.\d{3} ± ", capsys.readouterr().out)
    path = tmp_path / "choice.json"
    path.write_text(GotoChoice.fit([{**r, "layout": "dual-plan"} for r in _records()]).to_json())
    run = tmp_path / "run"
    assert main(["imitate", "--run-dir", str(run), "--observation", "dual-plan", "--choice", str(path),
                 "--iterations", "2", "--episodes", "2", "--updates", "2", "--envs", "1", "--net-arch", "8,8"]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("imitating plan under the setting") and "agreement with plan" in printed
    rows = [line.split(",") for line in (run / "imitation.csv").read_text().splitlines()]
    assert [r[1] for r in rows[1:]] == ["plan", "student"]


# --------------------------------------------------------------------------- tri-plan
def test_that_a_choice_file_of_one_threshold_written_before_tri_plan_still_loads(tmp_path: Path) -> None:
    bundled = Path(__file__).parents[2] / "training" / "checkpoints" / "plan-choice" / "choice.json"
    assert json.loads(bundled.read_text())["format"] == "tumblebot-goto-choice/1"
    choice = GotoChoice.load(bundled)
    assert choice.layout == "dual-plan" and choice.threshold == pytest.approx(1.361, abs=1e-3)
    data = json.loads(bundled.read_text())
    data["second"] = {**data["second"], "spin_steps_left": 5}
    path = tmp_path / "choice.json"
    path.write_text(json.dumps(data))
    with pytest.raises(TrainingError, match="pinned goto settings"):
        GotoChoice.load(path)


def _tri_records() -> list[dict[str, Any]]:
    """A made-up tri-plan sweep: setting 2 gains 0.03 above l/r 1.4, setting 3 gains 0.05
    below 1.15; each loses as much elsewhere."""
    records: list[dict[str, Any]] = []
    for d in tumbling_designs(300, seed=2):
        r = reach(d.as_tuple())[0]
        records.append({"design": list(d.as_tuple()), "layout": "tri-plan", "compared": [2, 3], "goto": 0.5,
                        "means": [0.0, 0.0], "differences": [0.03 if r > 1.4 else -0.03, 0.05 if r < 1.15 else -0.05],
                        "errors": [0.005, 0.005]})
    return records


def test_that_a_tri_plan_choice_takes_the_third_setting_on_short_legs_and_the_second_on_long_ones(
        tmp_path: Path) -> None:
    from tumblebot.sim.observation import PLAN_DUAL_GOTO, PLAN_GOTO, PLAN_SHORT_GOTO

    choice = GotoChoice.fit(_tri_records())
    assert choice.layout == "tri-plan" and choice.settings == (PLAN_GOTO, PLAN_DUAL_GOTO, PLAN_SHORT_GOTO)
    short = next(rule for rule in choice.rules if rule.setting == 3)
    assert short.side == "below" and 1.08 < short.threshold < 1.2
    assert 1.35 < choice.threshold < 1.5
    teacher = choice_teacher(choice)
    for d in tumbling_designs(200, seed=8):
        r = reach(d.as_tuple())[0]
        if abs(r - 1.15) > 0.05 and abs(r - 1.4) > 0.05:
            expected = PLAN_SHORT_GOTO if r < 1.15 else PLAN_DUAL_GOTO if r > 1.4 else PLAN_GOTO
            assert teacher(np.array(d.as_tuple())) == GotoConfig(**expected)
    path = tmp_path / "choice.json"
    path.write_text(choice.to_json())
    again = GotoChoice.load(path)
    assert [(r.setting, r.side, r.threshold) for r in again.rules] == [(r.setting, r.side, r.threshold)
                                                                      for r in choice.rules]
    assert "setting 3 where l/r < " in choice.summary()


def test_that_a_tri_plan_fit_reads_the_second_setting_from_a_dual_plan_sweep_and_the_third_from_its_own() -> None:
    tri = _tri_records()
    second_only = [{"design": r["design"], "layout": "dual-plan", "difference": r["differences"][0], "se": 0.005}
                   for r in tri]
    third_only = [{**r, "compared": [3], "means": [0.0], "differences": [r["differences"][1]], "errors": [0.005]}
                  for r in tri[:150]]
    both = GotoChoice.fit(tri)
    merged = GotoChoice.fit([*second_only, *third_only], "tri-plan")
    assert merged.threshold == both.threshold
    assert len(next(r for r in merged.rules if r.setting == 3).designs) == 150
    with pytest.raises(TrainingError, match="mixes the goto settings of dual-plan, tri-plan"):
        GotoChoice.fit([*second_only, *third_only])
    with pytest.raises(TrainingError, match="other goto settings than the tri-plan"):
        GotoChoice.fit([*_records(), *third_only], "tri-plan")  # dual's first setting is goto, not plan
    with pytest.raises(TrainingError, match="at least 5 swept designs for setting 3"):
        GotoChoice.fit(second_only, "tri-plan")


def test_that_a_sweep_compares_only_the_settings_asked_for_and_refuses_one_the_layout_lacks(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from tumblebot.training.choice import check_compared

    assert check_compared("tri-plan", None) == (2, 3) and check_compared("tri-plan", [3]) == (3,)
    with pytest.raises(TrainingError, match="later goto settings are 2, not 3"):
        check_compared("dual-plan", [3])
    out = tmp_path / "sweep.jsonl"
    assert main(["choice", "sweep", "--layout", "dual", "--compare", "3", "--out", str(out)]) == 2
    assert "not 3" in capsys.readouterr().err and not out.exists()
    with pytest.raises(SystemExit):
        main(["choice", "sweep", "--layout", "tri-plan", "--reach-below", "0.9", "--out", str(out)])
    assert "must be above 1" in capsys.readouterr().err and not out.exists()


@pytest.mark.slow
def test_that_a_sweep_below_a_reach_keeps_the_drawn_designs_numbers_and_pairs_the_third_setting(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sweep.jsonl"
    command = ["choice", "sweep", "--layout", "tri-plan", "--compare", "3", "--reach-below", "1.5", "--designs", "12",
               "--episodes", "2", "--workers", "1", "--out", str(out)]
    assert main(command) == 0
    records = read_sweep(out)
    drawn = tumbling_designs(12, seed=3)
    assert records and [r["index"] for r in records] == [k for k, d in enumerate(drawn) if reach(d.as_tuple())[0] < 1.5]
    for r in records:
        assert r["compared"] == [3] and "difference" not in r
        assert r["differences"][0] == pytest.approx(r["means"][0] - r["goto"])
    before = out.read_text()
    assert main(command) == 0 and out.read_text() == before  # done: continuing adds nothing
    capsys.readouterr()
