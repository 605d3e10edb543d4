"""Which of two ``goto`` settings suits a body: a sweep over the design space, and a
threshold fitted to its result, the teacher of the ``dual`` navigation policy.

``goto``'s best settings depend on the body it drives
(``reports/policy-headroom/README.md``): ``turn_tolerance`` 0.3 with ``spin_steps_left``
4 gains up to +0.04 mean final R on the thesis's robots and on bodies with medium legs,
and costs up to 0.03 on bodies with short legs. A ``dual`` policy
(:data:`tumblebot.sim.control.policy.LAYOUTS`) is shown the action of ``goto`` under both settings
(:data:`~tumblebot.sim.observation.RESIDUAL_GOTO` and :data:`~tumblebot.sim.observation.DUAL_GOTO`)
and the design; its teacher follows the second setting on the bodies where this module
predicts it does better. A ``dual-plan`` policy is the same with the two settings of
``plan``, the stronger hand-written controller
(:data:`~tumblebot.sim.observation.PLAN_GOTO` and
:data:`~tumblebot.sim.observation.PLAN_DUAL_GOTO`): every function here takes the layout
whose pair of settings it sweeps or fits (``dual`` by default).

1. :func:`sweep` drives ``nav-flat`` (or ``nav-terrain``) episodes on designs drawn uniformly over those that
   can tumble, under both settings, paired on the same episodes (the same randomisation
   as ``tumblebot evaluate``), and records each design's mean paired difference. Designs
   are appended to a JSON-lines file as they finish, so a stopped sweep resumes.
2. :class:`GotoChoice` reads the result: the second setting loses only on bodies whose
   legs barely tumble them, so it is chosen where the reach ``l / r`` exceeds a threshold
   fitted to the sweep (the highest whose summed gain is within one standard error of the
   best), and the first elsewhere.

    tumblebot choice sweep --designs 240 --episodes 48 --seed 3 [--layout dual-plan] \\
        --out training/checkpoints/goto-choice/sweep.jsonl
    tumblebot choice fit training/checkpoints/goto-choice/sweep.jsonl \\
        -o training/checkpoints/goto-choice/choice.json
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.control.drivers import episode_seed
from tumblebot.sim.control.goto import NAVIGATION_TASKS, GotoConfig, GotoController, check_navigation_task
from tumblebot.sim.evaluation.pool import WorkerPool
from tumblebot.sim.evaluation.rollout import GotoActor, run_episode
from tumblebot.sim.observation import DUAL_LAYOUTS, GOTO_SETTINGS
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.physics import THESIS, PhysicsProfile
from tumblebot.training.config import TrainingError

FORMAT = "tumblebot-goto-choice/1"
#: how a sweep's episodes are seeded: record lines without it seeded each design's own
#: episodes (an earlier tumblebot), and are not continued
SEEDING = "episode_seed"


def _sweep_env(physics: PhysicsProfile, task: str = "nav-flat") -> Any:
    """A worker's state: one ``task`` environment under ``physics``, every design its own."""
    from tumblebot.sim.world.env import TumblerEnv
    from tumblebot.sim.world.randomization import Randomization

    return TumblerEnv(task=task, randomization=physics.randomization(Randomization(design=False)),
                      **physics.env_kwargs())


def check_layout(layout: str) -> str:
    """``layout`` if its policies are shown two gotos (a choice is about them), else an error."""
    if layout not in DUAL_LAYOUTS:
        raise TrainingError(f"layout {layout!r} has no two goto settings to choose between "
                            f"(use {' or '.join(DUAL_LAYOUTS)})")
    return layout


def _episode(env: Any, job: tuple[tuple[float, ...], int, int, str]) -> tuple[float, float]:
    """Final R of episode ``index`` of seed ``seed`` under the two goto
    settings of ``layout`` (``dual``: ``RESIDUAL_GOTO`` and ``DUAL_GOTO``): the same
    episode (:func:`episode_seed`, as every evaluation seeds them), so the two are paired,
    and every design sees the same starts."""
    design, seed, index, layout = job
    options = {"design": Design.from_sequence(design)}
    first, second = (run_episode(env, GotoActor(GotoController(GotoConfig(**settings))), episode_seed(seed, index),
                                 options=options).final_R for settings in GOTO_SETTINGS[layout])
    return first, second


def sweep(designs: Sequence[Design], episodes: int, seed: int, workers: int, done: int = 0,
          should_stop: Callable[[], bool] = lambda: False,
          physics: PhysicsProfile = THESIS, layout: str = "dual", task: str = "nav-flat") -> Iterator[dict[str, Any]]:
    """Each design's record from ``done`` on: its two mean final Rs and the paired
    difference (second setting minus first) with its standard error, on ``task`` under
    ``physics``, for the two settings of ``layout``."""
    check_layout(layout)
    check_navigation_task(task)
    with WorkerPool(_sweep_env, (physics, task), workers) as pool:
        for index in range(done, len(designs)):
            if should_stop():
                return
            design = designs[index].as_tuple()
            R = np.array(pool.map(_episode, [(design, seed, e, layout) for e in range(episodes)], chunksize=4))
            diff = R[:, 1] - R[:, 0]
            yield {"index": index, "design": list(design), "episodes": episodes, "seed": seed,
                   "seeding": SEEDING, "physics": physics.digest(), "layout": layout, "task": task,
                   "goto": float(R[:, 0].mean()), "dual": float(R[:, 1].mean()),
                   "difference": float(diff.mean()), "se": float(diff.std(ddof=1) / np.sqrt(episodes))}


def read_sweep(path: Path) -> list[dict[str, Any]]:
    """The records of a sweep file (JSON lines); :class:`TrainingError` on a bad line."""
    records = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            Design.from_sequence(record["design"])
            float(record["difference"])
            if record.get("layout", "dual") not in DUAL_LAYOUTS:
                raise ValueError(f"layout {record.get('layout')!r} is not one of {', '.join(DUAL_LAYOUTS)}")
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise TrainingError(f"{path}:{number}: not a sweep record ({exc})") from None
        records.append(record)
    return records


def reach(design: Sequence[float] | np.ndarray) -> np.ndarray:
    """``l / r`` of each design ``(x, y, z, l)``: leg length over the pivot radius (1 where
    the legs just tumble the body)."""
    d = np.asarray(design, dtype=float).reshape(-1, 4)
    out: np.ndarray = d[:, 3] / np.hypot(d[:, 1] / 2, d[:, 2] / 2)
    return out


@dataclass(frozen=True)
class GotoChoice:
    """Where ``goto``'s ``DUAL_GOTO`` settings beat ``RESIDUAL_GOTO``: on bodies whose
    reach ``l / r`` exceeds ``threshold``. The sweep shows the second setting losing only
    on bodies whose legs barely tumble them, so one threshold on the reach is the model;
    :meth:`fit` takes, among the thresholds whose summed paired gain over the swept
    designs is within one standard error of the best, the highest (the second setting on
    the fewest bodies: the one-standard-error rule)."""

    threshold: float  #: l / r above which the second setting labels the episode
    designs: np.ndarray  #: (N, 4) swept designs, m
    differences: np.ndarray  #: (N,) mean paired difference of each (second − first)
    errors: np.ndarray  #: (N,) its standard error
    layout: str = "dual"  #: the policy layout whose two goto settings it chooses between
    task: str = "nav-flat"  #: the task the sweep drove

    @property
    def settings(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """The first and the second goto settings (:data:`~tumblebot.sim.observation.GOTO_SETTINGS`)."""
        first, second = GOTO_SETTINGS[self.layout]
        return first, second

    @classmethod
    def fit(cls, records: Sequence[dict[str, Any]]) -> GotoChoice:
        if len(records) < 5:
            raise TrainingError(f"a goto choice needs at least 5 swept designs, not {len(records)}")
        layouts = {r.get("layout", "dual") for r in records}  # sweeps before dual-plan were of dual
        if len(layouts) != 1:
            raise TrainingError(f"the sweep mixes the goto settings of {', '.join(sorted(layouts))}")
        tasks = {r.get("task", "nav-flat") for r in records}  # sweeps before nav-terrain ones were of nav-flat
        if len(tasks) != 1:
            raise TrainingError(f"the sweep mixes the tasks {', '.join(sorted(tasks))}")
        layout = check_layout(layouts.pop())
        designs = np.array([r["design"] for r in records], dtype=float)
        differences = np.array([r["difference"] for r in records], dtype=float)
        errors = np.array([r.get("se", 0.0) for r in records], dtype=float)
        ratios = reach(designs)
        order = np.argsort(ratios)
        ratios, gains, variances = ratios[order], differences[order], errors[order] ** 2
        # threshold k: just below design k in reach order (k = N: the second setting nowhere)
        candidates = np.append((np.append(0.0, ratios[:-1]) + ratios) / 2, ratios[-1] + 1e-6)
        totals = np.append(np.cumsum(gains[::-1])[::-1], 0.0)  # gain summed over designs above each
        best = int(np.argmax(totals))
        chosen = best
        for k in range(best + 1, len(candidates)):
            lost = totals[best] - totals[k]
            if lost <= float(np.sqrt(variances[best:k].sum())):
                chosen = k
        return cls(float(candidates[chosen]), designs, differences, errors, layout, tasks.pop())

    def prefers_dual(self, design: Sequence[float] | np.ndarray) -> bool:
        return bool(reach(design)[0] > self.threshold)

    def summary(self) -> str:
        above = reach(self.designs) > self.threshold
        def mean(where: np.ndarray) -> str:
            return f"{self.differences[where].mean():+.4f}" if where.any() else "none"

        return (f"the second goto setting where l/r > {self.threshold:.3f}: {above.sum()} of {len(above)} swept "
                f"{self.task} designs, mean paired difference there {mean(above)}, below {mean(~above)}")

    def to_json(self) -> str:
        first, second = self.settings
        return json.dumps({"format": FORMAT, "layout": self.layout, "task": self.task, "first": first, "second": second,
                           "rule": "l/r > threshold",
                           "threshold": self.threshold, "designs": self.designs.tolist(),
                           "differences": self.differences.tolist(), "errors": self.errors.tolist()}, indent=1) + "\n"

    @classmethod
    def load(cls, path: Path) -> GotoChoice:
        try:
            data = json.loads(Path(path).read_text())
            layout = data.get("layout", "dual")  # files before dual-plan were of dual
            task = data.get("task", "nav-flat")  # ... and before nav-terrain of nav-flat
            if task not in NAVIGATION_TASKS:
                raise ValueError(f"task {task!r} is not one of {', '.join(NAVIGATION_TASKS)}")
            if data.get("format") != FORMAT or layout not in DUAL_LAYOUTS \
                    or [data.get("first"), data.get("second")] != list(GOTO_SETTINGS[layout]):
                raise ValueError(f"not a {FORMAT} file for the pinned goto settings")
            choice = cls(float(data["threshold"]), np.array(data["designs"], dtype=float).reshape(-1, 4),
                         np.array(data["differences"], dtype=float), np.array(data["errors"], dtype=float), layout,
                         task)
        except (OSError, json.JSONDecodeError, AttributeError, KeyError, TypeError, ValueError) as exc:
            raise TrainingError(f"goto choice {path}: {exc}") from None
        if not len(choice.designs) == len(choice.differences) == len(choice.errors) \
                or not np.isfinite(choice.threshold):
            raise TrainingError(f"goto choice {path}: inconsistent designs, differences, errors or threshold")
        return choice
