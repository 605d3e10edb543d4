"""Training on one chosen body (the reproduction's retrain check)."""

from __future__ import annotations

import pytest

from tumblebot.defaults import XI3_ROBOT
from tumblebot.training.config import TrainConfig, TrainingError
from tumblebot.training.ppo import make_env

XI3 = list(XI3_ROBOT)


def test_that_a_fixed_design_is_the_body_of_every_training_episode() -> None:
    config = TrainConfig(design=XI3, observation="context")
    env = make_env(config.task, config.reward_weights(), config.randomization(), config.profile(),
                   config.observation, config.design)
    try:
        for seed in range(3):
            _, info = env.reset(seed=seed)
            assert list(info["design"]) == XI3
    finally:
        env.close()


@pytest.mark.parametrize("design", [[0.29, 0.12, 0.1], [0.29, 0.12, 0.1, "x"], [0.1, 0.129, 0.098, 0.136], "0.3"])
def test_that_a_bad_fixed_design_is_one_clear_error(design: object) -> None:
    with pytest.raises(TrainingError, match="design"):
        TrainConfig(design=design)  # type: ignore[arg-type]
