"""The shared statistics: the 95 % interval of a mean and the paired test."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from tumblebot.sim.evaluation.stats import mean_ci95, paired_p


def test_that_the_interval_is_the_student_t_interval_of_the_mean() -> None:
    x = np.random.default_rng(3).normal(0.7, 0.2, size=48)
    expected = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))
    assert mean_ci95(x) == pytest.approx(expected, rel=1e-12)


def test_that_one_value_gives_a_zero_width_interval_and_none_is_an_error() -> None:
    assert mean_ci95([0.5]) == (0.5, 0.5)
    with pytest.raises(ValueError, match="at least one value"):
        mean_ci95([])


def test_that_the_paired_p_is_the_paired_t_test() -> None:
    rng = np.random.default_rng(5)
    a = rng.normal(0.8, 0.1, size=48)
    b = a - rng.normal(0.02, 0.05, size=48)
    assert paired_p(a, b) == pytest.approx(stats.ttest_rel(a, b).pvalue, rel=1e-12)


def test_that_paired_differences_without_spread_are_certain_either_way() -> None:
    a = np.array([0.9, 0.5, 0.7])
    assert paired_p(a, a.copy()) == 1.0  # the same episodes, the same scores: no difference
    assert paired_p(a, a - 0.1) == 0.0  # ahead by the same amount on every episode
    assert paired_p(a, a[:2]) is None
    assert paired_p(a[:1], a[:1]) is None
