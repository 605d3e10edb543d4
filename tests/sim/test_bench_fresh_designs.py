"""benchmarks/bench_fresh_designs.py: the cross-fitted comparison with the strongest controller."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from tests.helpers import load_script

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_fresh_designs.py"


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    return load_script(SCRIPT, "bench_fresh_designs")


def test_that_the_strongest_is_taken_on_each_set_or_chosen_on_the_other(bench: ModuleType) -> None:
    # plan is the luckier controller on the first set, plan-short on the second
    first = {"policy": np.array([0.80, 0.80]), "plan": np.array([0.84, 0.84]), "plan-short": np.array([0.78, 0.78])}
    second = {"policy": np.array([0.80, 0.80]), "plan": np.array([0.76, 0.76]), "plan-short": np.array([0.82, 0.82])}
    same, crossed = bench.cross_fit(first, second, ["plan", "plan-short"])
    assert same == pytest.approx(((0.80 - 0.84) + (0.80 - 0.82)) / 2)
    # chosen on the other set: plan-short measured on the first, plan on the second
    assert crossed == pytest.approx(((0.80 - 0.78) + (0.80 - 0.76)) / 2)


def test_that_a_policy_as_good_as_three_noisy_equals_is_behind_only_on_the_same_episodes(bench: ModuleType) -> None:
    """Four drivers of the same true mean: the maximum of three noisy means taken on the
    episodes compared on puts the policy behind; chosen on other episodes it is level."""
    rng = np.random.default_rng(0)
    hand = ["goto", "plan", "plan-short"]
    same, crossed = [], []
    for _ in range(400):
        sets = [{n: rng.normal(0.8, 0.15, 48) for n in ("policy", *hand)} for _ in range(2)]
        s, c = bench.cross_fit(sets[0], sets[1], hand)
        same.append(s)
        crossed.append(c)
    assert np.mean(same) < -0.015  # E[max of 3 standard normals] ≈ 0.85 standard errors of 0.022
    assert abs(np.mean(crossed)) < 0.004
