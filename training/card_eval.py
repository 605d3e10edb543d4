"""The evaluation a model card records: the policy against scripted gaits and a random
policy, on the thesis's ξ = 3 robot and on a design drawn from the bounds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from tumblebot.sim.design import THESIS_ROBOTS, Design
from tumblebot.sim.evaluate import Controller, EvalResult, evaluate
from tumblebot.sim.gaits import GAITS

XI3_ROBOT = THESIS_ROBOTS["3"]


def _first_tumbling_draw(seed: int) -> Design:
    """The first design drawn uniformly from the bounds with ``seed`` whose legs can lift
    the body (``l >= r``). The very first draw of seed 2021, (0.273, 0.241, 0.153, 0.125),
    cannot tumble at all, so every controller scores the same there and the card's
    comparison would say nothing about the policy."""
    rng = np.random.default_rng(seed)
    while True:
        design = Design.sample(rng)
        if design.can_tumble:
            return design


#: The random design of the model cards: (0.258, 0.107, 0.113, 0.155).
RANDOM_DESIGN = _first_tumbling_draw(2021)
FIXED_GAITS = [g for g in GAITS if g != "random"]


def _welch(a: EvalResult, b: EvalResult) -> float:
    """One-sided p-value that ``a`` has a higher mean R than ``b`` (Welch's t-test)."""
    return float(stats.ttest_ind(a.R, b.R, equal_var=False, alternative="greater").pvalue)


def card_evaluation(policy: Path, task: str, episodes: int, seed: int, workers: int) -> dict[str, Any]:
    out: dict[str, Any] = {"episodes_per_design": episodes, "seed": seed, "designs": {}}
    for label, design in (("xi3_robot", XI3_ROBOT), ("random_design", RANDOM_DESIGN)):
        pol = evaluate(task, design, Controller("onnx", str(policy)), episodes, seed, workers, progress=True)
        gaits = {g: evaluate(task, design, Controller("gait", g), episodes, seed, workers, progress=True)
                 for g in [*FIXED_GAITS, "random"]}
        best_fixed = max(FIXED_GAITS, key=lambda g: gaits[g].mean_R)
        entry = pol.summary()
        entry["baselines"] = {g: {"mean_R": r.mean_R, "ci95": list(r.ci95)} for g, r in gaits.items()}
        entry["best_fixed_gait"] = best_fixed
        entry["p_vs_best_fixed_gait"] = _welch(pol, gaits[best_fixed])
        entry["p_vs_random_policy"] = _welch(pol, gaits["random"])
        out["designs"][label] = entry
    return out
