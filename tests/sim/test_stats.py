"""The shared 95 % interval of a mean."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from tumblebot.sim.evaluation.stats import mean_ci95


def test_that_the_interval_is_the_student_t_interval_of_the_mean() -> None:
    x = np.random.default_rng(3).normal(0.7, 0.2, size=48)
    expected = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))
    assert mean_ci95(x) == pytest.approx(expected, rel=1e-12)


def test_that_one_value_gives_a_zero_width_interval_and_none_is_an_error() -> None:
    assert mean_ci95([0.5]) == (0.5, 0.5)
    with pytest.raises(ValueError, match="at least one value"):
        mean_ci95([])
