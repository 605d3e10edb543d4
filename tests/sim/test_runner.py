"""EpisodeRunner: controllers side by side on one pool give what each gives alone."""

from __future__ import annotations

import numpy as np
import pytest

from tumblebot.sim.control.drivers import Driver
from tumblebot.sim.errors import SimError
from tumblebot.sim.evaluation.evaluate import evaluate, evaluate_with
from tumblebot.sim.evaluation.runner import EpisodeRunner
from tumblebot.sim.world.design import THESIS_ROBOTS
from tumblebot.sim.world.tasks import get_task

XI3 = THESIS_ROBOTS["3"]


def test_that_controllers_side_by_side_on_one_pool_score_as_each_does_alone() -> None:
    alone = {name: evaluate("nav-flat", XI3, Driver.of_gait(name), episodes=4, seed=5, workers=1).R
             for name in ("goto", "plan", "random")}
    lanes = {name: Driver.of_gait(name) for name in alone}
    with EpisodeRunner(lanes, workers=2, task="nav-flat") as runner:
        together = runner.run(XI3, list(lanes), 0, 4, 5)  # interleaved on two workers sharing environments
        assert set(together) == set(alone)
        for name in alone:
            np.testing.assert_array_equal(together[name], alone[name])
        one = evaluate_with(runner, "plan", XI3, episodes=4, seed=5)
        np.testing.assert_array_equal(one.R, alone["plan"])
        assert one.task == "nav-flat" and one.controller == Driver.of_gait("plan").label()
    assert not np.array_equal(alone["goto"], alone["plan"])  # the lanes did drive differently


def test_that_a_lane_not_given_is_refused_by_name() -> None:
    with EpisodeRunner({"a": Driver.of_gait("goto")}, task="nav-flat") as runner:
        with pytest.raises(SimError, match=r"no controller given for 'b' \(this runner has a\)"):
            runner.run(XI3, ["b"], 0, 1, 0)
        with pytest.raises(SimError, match="no controller given for 'nav-flat'"):
            runner.run(XI3, ["nav-flat"], 0, 1, 0)  # side by side, lanes are the caller's labels only
    with EpisodeRunner({"nav-flat": Driver.of_gait("goto")}) as runner:
        env_id = get_task("nav-flat").env_id
        assert list(runner.run(XI3, [env_id], 0, 1, 0)) == ["nav-flat"]  # a task by any of its names
        with pytest.raises(SimError, match="no controller given for 'incline'"):
            runner.run(XI3, ["incline"], 0, 1, 0)
    with pytest.raises(SimError, match="at least one controller"):
        EpisodeRunner({})
