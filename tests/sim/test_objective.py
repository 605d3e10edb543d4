import math

import pytest

from tumblebot.sim.errors import SimError
from tumblebot.sim.evaluation.score import wrap_reward


def test_that_the_thesis_wrapper_divides_by_e_plus_one_to_the_xi() -> None:
    assert wrap_reward(0.87, 5.2, 3) == pytest.approx(0.87 / 6.2**3)
    assert wrap_reward(0.87, 5.2, 0) == pytest.approx(0.87)


def test_that_xi_infinity_ranks_designs_by_e_alone() -> None:
    assert wrap_reward(0.1, 3.76, math.inf) > wrap_reward(0.9, 6.05, math.inf)


def test_that_the_thesis_form_rewards_larger_e_for_negative_r_and_the_monotone_form_does_not() -> None:
    assert wrap_reward(-1.0, 6.0, 1) > wrap_reward(-1.0, 3.0, 1)
    assert wrap_reward(-1.0, 6.0, 1, "monotone") < wrap_reward(-1.0, 3.0, 1, "monotone")
    assert wrap_reward(0.5, 6.0, 1, "monotone") == wrap_reward(0.5, 6.0, 1)


def test_that_designs_that_cannot_tumble_score_zero_or_worst() -> None:
    assert wrap_reward(0.8, math.inf, 3) == 0.0
    assert wrap_reward(0.8, math.inf, math.inf) == -math.inf


@pytest.mark.parametrize(("xi", "e", "variant"), [(-1.0, 5.0, "thesis"), (math.nan, 5.0, "thesis"),
                                                 (1.0, math.nan, "thesis"), (1.0, 5.0, "other")])
def test_that_bad_arguments_raise_one_clear_error(xi: float, e: float, variant: str) -> None:
    with pytest.raises(SimError):
        wrap_reward(0.5, e, xi, variant)  # type: ignore[arg-type]
