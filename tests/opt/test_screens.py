"""Which episodes an efficient study runs: screens of their own, full batches shared."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np
import optuna

from tumblebot.sim.control.drivers import episode_seed
from tumblebot.sim.optimize import Objective, Recipe, StudyConfig, open_storage, open_study, optimize, promotions
from tumblebot.sim.optimize.storage import STUDY_KEY
from tumblebot.sim.optimize.trials import OWN_SCREENS_FROM, screen_episodes
from tumblebot.sim.world.design import Design


class EpisodeLedger:
    """An episode runner whose every episode's R follows from its design and its episode's
    seed alone (as a real one's does), and that writes down which episodes were asked for."""

    def __init__(self) -> None:
        self.asked: list[tuple[tuple[float, ...], int, int]] = []

    def run(self, design: Design, tasks: list[str], start: int, stop: int, seed: int,
            on_result: Callable[[], object] | None = None) -> dict[str, np.ndarray]:
        self.asked.append((design.as_tuple(), start, stop))
        w = np.array(design.as_tuple())
        luck = np.array([episode_seed(seed, i) % 1000 / 1000 for i in range(start, stop)])
        for _ in range(start, stop):
            if on_result is not None:
                on_result()
        return {t: 0.9 - 20 * float(((w - 0.15) ** 2).sum()) + 0.2 * (luck - 0.5) for t in tasks}


OBJECTIVE = Objective({"nav-flat": 1.0}, 3.0)
RECIPE = Recipe("efficient", 12, 24, 12, 4, promote_every=0, final_promotions=1)
SAME = {"x": 0.25, "y": 0.15, "z": 0.12, "l": 0.2}


def _study(tmp_path: Path, name: str, recipe: Recipe = RECIPE) -> optuna.Study:
    return open_study(open_storage(f"sqlite:///{tmp_path / 's.db'}"), name, StudyConfig.of(OBJECTIVE, recipe, 0, {}))


def test_that_every_screen_runs_episodes_no_other_trial_runs_and_promotions_add_the_shared_ones(
        tmp_path: Path) -> None:
    study = _study(tmp_path, "own")
    study.enqueue_trial(SAME)
    study.enqueue_trial(SAME)  # the same body screened twice: two looks, not one look twice
    ledger = EpisodeLedger()
    optimize(study, OBJECTIVE, RECIPE, ledger, 0)  # type: ignore[arg-type]
    screens = [(a, b) for _, a, b in ledger.asked if b - a == RECIPE.screen_batch]
    episodes = [i for a, b in screens for i in range(a, b)]
    assert len(screens) >= 3 and len(set(episodes)) == len(episodes)  # no episode screened twice
    assert min(episodes) >= OWN_SCREENS_FROM  # nor one a full batch runs
    first, second = study.trials[0].user_attrs["R"]["nav-flat"], study.trials[1].user_attrs["R"]["nav-flat"]
    assert first != second
    extensions = [(a, b) for _, a, b in ledger.asked if b - a != RECIPE.screen_batch]
    assert extensions == [(RECIPE.screen_batch, RECIPE.batch)]  # a promotion: episodes s..B-1, as every full batch
    (number, promoted), = promotions(study).items()
    assert promoted["R"]["nav-flat"][:4] == study.trials[number].user_attrs["R"]["nav-flat"]
    assert screen_episodes(study, number, RECIPE) == (OWN_SCREENS_FROM + 4 * number, OWN_SCREENS_FROM + 4 * number + 4)


def test_that_a_study_made_with_shared_screens_resumes_with_them(tmp_path: Path) -> None:
    """A study written before own screens existed has no ``screens`` in its record: it is
    opened by today's command without complaint and goes on screening episodes 0..s-1."""
    study = _study(tmp_path, "old")
    record = asdict(StudyConfig.of(OBJECTIVE, RECIPE, 0, {}))
    del record["screens"]
    study.set_user_attr(STUDY_KEY, record)
    study = _study(tmp_path, "old")
    ledger = EpisodeLedger()
    optimize(study, OBJECTIVE, RECIPE, ledger, 0)  # type: ignore[arg-type]
    assert {(a, b) for _, a, b in ledger.asked} == {(0, 4), (4, 24)}


def test_that_a_standard_study_runs_every_design_on_the_same_full_batch(tmp_path: Path) -> None:
    standard = Recipe("standard", 3, 6, 3, 6)
    study = _study(tmp_path, "std", standard)
    ledger = EpisodeLedger()
    optimize(study, OBJECTIVE, standard, ledger, 0)  # type: ignore[arg-type]
    assert [(a, b) for _, a, b in ledger.asked] == [(0, 6)] * 3
