"""reports/policy-headroom/planners.py: the hand-written alternatives to ``plan`` it measures."""

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from tests.helpers import load_script
from tumblebot.defaults import XI3_ROBOT
from tumblebot.sim.control.goto import NAVIGATORS, SPIN_NEGATIVE, SPIN_POSITIVE, GotoController
from tumblebot.sim.evaluation.rollout import GotoActor, run_episode
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.env import TumblerEnv
from tumblebot.sim.world.randomization import Randomization

SCRIPT = Path(__file__).resolve().parents[2] / "reports" / "policy-headroom" / "planners.py"


@pytest.fixture(scope="module")
def planners() -> ModuleType:
    return load_script(SCRIPT, "planners")


def test_that_each_controller_name_builds_the_controller_it_names(planners: ModuleType) -> None:
    assert planners.controller("plan").config == NAVIGATORS["plan"]
    assert planners.controller("goto").config == NAVIGATORS["goto"]
    assert planners.controller("turn_tolerance=0.5;memory=0.3").config.turn_tolerance == 0.5
    assert isinstance(planners.controller("near=1"), planners.NoSpinNearGoal)
    assert planners.controller("predict=0.02").spin_cost == 0.02
    with pytest.raises(ValueError, match="expected goto"):
        planners.controller("nonsense=1")


def _actions(controller: GotoController, env: TumblerEnv, seed: int) -> tuple[list[tuple[int, int]], float]:
    taken: list[tuple[int, int]] = []

    def on_step(step: int, action: np.ndarray, obs: np.ndarray, info: dict[str, object]) -> None:
        taken.append((int(action[0]), int(action[1])))

    out = run_episode(env, GotoActor(controller), seed, {"design": Design(*XI3_ROBOT)}, on_step)
    return taken, out.final_R


def test_that_near_spins_as_plan_far_from_the_goal_and_never_within_its_reach(planners: ModuleType) -> None:
    env = TumblerEnv(task="nav-flat", randomization=Randomization(design=False))
    try:
        spun = False
        for seed in range(4):
            plan, plan_R = _actions(planners.controller("plan"), env, seed)
            assert _actions(planners.controller("near=0"), env, seed) == (plan, plan_R)
            spun |= any(a in (SPIN_POSITIVE, SPIN_NEGATIVE) for a in plan)
            never, _ = _actions(planners.controller("near=100"), env, seed)  # the ring is closer than 100 steps
            assert not any(a in (SPIN_POSITIVE, SPIN_NEGATIVE) for a in never)
        assert spun
    finally:
        env.close()


def test_that_predict_spins_drives_and_stops_in_real_episodes(planners: ModuleType) -> None:
    env = TumblerEnv(task="nav-flat", randomization=Randomization(design=False))
    try:
        seen: set[tuple[int, int]] = set()
        for seed in range(4):
            actions, R = _actions(planners.controller("predict=0.02"), env, seed)
            seen |= set(actions)
            assert actions[-1] == (1, 1) and np.isfinite(R)  # the last step stops
        assert {(2, 2), (0, 0)} & seen and {SPIN_POSITIVE, SPIN_NEGATIVE} & seen
    finally:
        env.close()


def test_that_the_script_prints_one_row_per_design_and_refuses_an_unknown_controller(
        planners: ModuleType, capsys: pytest.CaptureFixture[str]) -> None:
    assert planners.main(["--designs", "1", "--episodes", "2", "--workers", "1", "--controller", "near=1"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[-1].startswith("mean over the designs") and len(out) == 4
    assert planners.main(["--controller", "bogus", "--designs", "1"]) == 2
    assert "planners: " in capsys.readouterr().err


def test_that_reach_below_keeps_the_same_draws_filtered_to_short_legs(planners: ModuleType,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    from tumblebot.sim.world.design import tumbling_designs

    short = tumbling_designs(3, 17, reach_below=1.2)
    assert len(short) == 3 and all(d.reach < 1.2 for d in short)
    assert short == [d for d in tumbling_designs(200, 17) if d.reach < 1.2][:3]
    assert tumbling_designs(3, 17, None) == tumbling_designs(3, 17)
    with pytest.raises(ValueError, match="must exceed 1"):
        tumbling_designs(3, 17, reach_below=1.0)
    with pytest.raises(SystemExit) as stop:
        planners.main(["--controller", "plan", "--reach-below", "0.9"])
    assert stop.value.code == 2 and "must be above 1" in capsys.readouterr().err


def test_that_reach_above_keeps_the_same_draws_filtered_to_long_legs_and_refuses_bounds_nothing_meets(
        planners: ModuleType, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    from tumblebot.sim.world import design as design_module
    from tumblebot.sim.world.design import tumbling_designs

    drawn = tumbling_designs(300, 29)
    assert tumbling_designs(3, 29, reach_above=1.8) == [d for d in drawn if d.reach >= 1.8][:3]
    assert tumbling_designs(3, 29, reach_below=1.361, reach_above=1.209) == [
        d for d in drawn if 1.209 <= d.reach < 1.361][:3]
    with pytest.raises(ValueError, match="must be below reach_below"):
        tumbling_designs(3, 29, reach_below=1.3, reach_above=1.3)
    monkeypatch.setattr(design_module, "MAX_DRAWS", 2000)
    with pytest.raises(ValueError, match=r"reach at least 50\.0 pivot radii: too few"):
        tumbling_designs(1, 29, reach_above=50.0)  # no leg in the bounds reaches 50 pivot radii
    assert planners.main(["--controller", "plan", "--reach-above", "50"]) == 2
    assert "planners: only 0 of 12 designs in 2000 draws" in capsys.readouterr().err
    assert planners.main(["--controller", "plan", "--reach-above", "1.5", "--reach-below", "1.4"]) == 2
    assert "--reach-above must be below --reach-below" in capsys.readouterr().err


def test_that_a_controller_paired_with_itself_as_the_baseline_differs_by_exactly_zero(
        planners: ModuleType, capsys: pytest.CaptureFixture[str]) -> None:
    setting = "turn_tolerance=0.3;spin_steps_left=4"
    assert planners.main(["--designs", "1", "--episodes", "2", "--workers", "1", "--reach-above", "1.4",
                          "--baseline", setting, "--controller", setting, "--controller", "plan"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert f"the baseline {setting}" in out[0] and out[1].split()[6] == "base"
    row = out[2].split()
    assert float(row[4]) >= 1.4 and row[6:8] == ["+0.000", "±0.000"]
    assert planners.main(["--controller", "plan", "--baseline", "bogus"]) == 2
    assert "'bogus'" in capsys.readouterr().err
