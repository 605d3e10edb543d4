"""Small statistics shared by evaluation, the optimiser's report and field-trial analysis."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def mean_ci95(values: Sequence[float] | np.ndarray) -> tuple[float, float]:
    """Two-sided 95 % Student-t interval of the mean; ``(mean, mean)`` for fewer than two values."""
    from scipy import stats

    x = np.asarray(values, dtype=float)
    if x.size == 0:
        raise ValueError("mean_ci95 needs at least one value")
    mean = float(x.mean())
    if x.size < 2:
        return (mean, mean)
    half = float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size))
    return (mean - half, mean + half)


def paired_p(a: np.ndarray, b: np.ndarray) -> float | None:
    """Two-sided paired t-test p-value (episodes shared by common random numbers): 1 where
    every paired difference is 0, 0 where every one is the same other number; ``None``
    unless ``a`` and ``b`` hold the same number (at least two) of values."""
    from scipy import stats

    if len(a) < 2 or len(a) != len(b):
        return None
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    if np.allclose(d, d[0]):  # no spread: the t statistic is 0/0 or ±∞
        return 1.0 if np.allclose(d, 0.0) else 0.0
    return float(stats.ttest_rel(a, b).pvalue)
