"""Which of a layout's ``goto`` settings suits a body: a sweep over the design space, and
thresholds on the reach fitted to its result, the teacher of the ``dual`` navigation policies.

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
:data:`~tumblebot.sim.observation.PLAN_DUAL_GOTO`). A ``tri-plan`` policy is also shown
``plan`` with a wider turning tolerance (:data:`~tumblebot.sim.observation.PLAN_SHORT_GOTO`),
which gains on bodies whose legs barely tumble them. Every function here takes the layout
whose settings it sweeps or fits (``dual`` by default).

1. :func:`sweep` drives ``nav-flat`` (or ``nav-terrain``) episodes on designs drawn uniformly over those that
   can tumble, under the first setting and each later one, paired on the same episodes (the same randomisation
   as ``tumblebot evaluate``), and records each design's mean paired differences. Designs
   are appended to a JSON-lines file as they finish, so a stopped sweep resumes.
2. :class:`GotoChoice` reads the result: each later setting is taken on one side of a
   threshold on the reach ``l / r`` (:data:`SIDES`: the second above, ``tri-plan``'s third
   below), fitted to the sweep (among the thresholds whose summed gain is within one
   standard error of the best, the one that takes the setting on the fewest bodies), and
   the first elsewhere. A fit may read several sweeps: records of another layout count
   where they compared the same pair of settings.

    tumblebot choice sweep --designs 240 --episodes 48 --seed 3 [--layout dual-plan] \\
        --out training/checkpoints/goto-choice/sweep.jsonl
    tumblebot choice fit training/checkpoints/goto-choice/sweep.jsonl \\
        -o training/checkpoints/goto-choice/choice.json
    tumblebot choice sweep --layout tri-plan --compare 3 --reach-below 1.6 --out short.jsonl
    tumblebot choice fit --layout tri-plan dual-plan-sweep.jsonl short.jsonl -o choice.json
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
from tumblebot.sim.observation import CHOICE_LAYOUTS, GOTO_SETTINGS
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.physics import THESIS, PhysicsProfile
from tumblebot.training.config import TrainingError

FORMAT = "tumblebot-goto-choice/2"
FORMAT_ONE_RULE = "tumblebot-goto-choice/1"  #: files of one rule (the second setting above a threshold)
#: how a sweep's episodes are seeded: record lines without it seeded each design's own
#: episodes (an earlier tumblebot), and are not continued
SEEDING = "episode_seed"


def _sweep_env(physics: PhysicsProfile, task: str = "nav-flat") -> Any:
    """A worker's state: one ``task`` environment under ``physics``, every design its own."""
    return physics.make_env(task)


def check_layout(layout: str) -> str:
    """``layout`` if its policies are shown several gotos (a choice is about them), else an error."""
    if layout not in CHOICE_LAYOUTS:
        raise TrainingError(f"layout {layout!r} has no goto settings to choose among "
                            f"(use {', '.join(CHOICE_LAYOUTS)})")
    return layout


def check_compared(layout: str, compared: Sequence[int] | None) -> tuple[int, ...]:
    """The numbers of the later settings of ``layout`` a sweep compares with the first
    (default: all of them), or an error naming the ones it has."""
    later = tuple(range(2, len(GOTO_SETTINGS[check_layout(layout)]) + 1))
    chosen = tuple(sorted(set(compared))) if compared else later
    if not set(chosen) <= set(later):
        raise TrainingError(f"the {layout} layout's later goto settings are {', '.join(map(str, later))}, "
                            f"not {', '.join(str(k) for k in chosen if k not in later)}")
    return chosen


def _episode(env: Any, job: tuple[tuple[float, ...], int, int, str, tuple[int, ...]]) -> tuple[float, ...]:
    """Final R of episode ``index`` of seed ``seed`` under the first goto setting of
    ``layout`` and each setting numbered in ``compared``: the same episode
    (:func:`episode_seed`, as every evaluation seeds them), so they are paired, and every
    design sees the same starts."""
    design, seed, index, layout, compared = job
    options = {"design": Design.from_sequence(design)}
    settings = GOTO_SETTINGS[layout]
    return tuple(run_episode(env, GotoActor(GotoController(GotoConfig(**settings[k - 1]))), episode_seed(seed, index),
                             options=options).final_R for k in (1, *compared))


def sweep(designs: Sequence[Design], episodes: int, seed: int, workers: int, done: int = 0,
          should_stop: Callable[[], bool] = lambda: False,
          physics: PhysicsProfile = THESIS, layout: str = "dual", task: str = "nav-flat",
          compared: Sequence[int] | None = None, indices: Sequence[int] | None = None) -> Iterator[dict[str, Any]]:
    """Each design's record from ``done`` on: the first setting's mean final R, and each
    compared setting's (default: every later one of ``layout``) with its paired difference
    (it minus the first) and standard error, on ``task`` under ``physics``. ``indices``
    numbers the designs in the record (default 0, 1, …: a sweep that skips some of the
    designs it draws keeps their places)."""
    compared = check_compared(layout, compared)
    check_navigation_task(task)
    indices = list(range(len(designs))) if indices is None else list(indices)
    with WorkerPool(_sweep_env, (physics, task), workers) as pool:
        for position in range(done, len(designs)):
            if should_stop():
                return
            design = designs[position].as_tuple()
            R = np.array(pool.map(_episode, [(design, seed, e, layout, compared) for e in range(episodes)],
                                  chunksize=4))
            diffs = R[:, 1:] - R[:, :1]
            means = [float(v) for v in R[:, 1:].mean(axis=0)]
            differences = [float(v) for v in diffs.mean(axis=0)]
            errors = [float(v) for v in diffs.std(axis=0, ddof=1) / np.sqrt(episodes)]
            record: dict[str, Any] = {
                "index": indices[position], "design": list(design), "episodes": episodes, "seed": seed,
                "seeding": SEEDING, "physics": physics.digest(), "layout": layout, "task": task,
                "goto": float(R[:, 0].mean()), "compared": list(compared),
                "means": means, "differences": differences, "errors": errors}
            if 2 in compared:  # the keys every sweep has had
                k = compared.index(2)
                record.update({"dual": means[k], "difference": differences[k], "se": errors[k]})
            yield record


def read_sweep(path: Path) -> list[dict[str, Any]]:
    """The records of a sweep file (JSON lines); :class:`TrainingError` on a bad line."""
    records = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            Design.from_sequence(record["design"])
            if record.get("layout", "dual") not in CHOICE_LAYOUTS:
                raise ValueError(f"layout {record.get('layout')!r} is not one of {', '.join(CHOICE_LAYOUTS)}")
            comparisons(record)
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


#: for each choice layout, the side of the reach on which each later goto setting (by the
#: number of its fields: 2 for ``goto2_*``, 3 for ``goto3_*``) is taken: the second setting
#: turns more tightly and gains on long legs, ``tri-plan``'s third turns less tightly and
#: gains on legs that barely tumble the body
SIDES: dict[str, dict[int, str]] = {"dual": {2: "above"}, "dual-plan": {2: "above"},
                                    "tri-plan": {2: "above", 3: "below"}}


def comparisons(record: dict[str, Any]) -> dict[int, tuple[float, float]]:
    """A sweep record's paired differences (each later setting minus the first) and their
    standard errors, by setting number; records before ``--compare`` compared setting 2 alone."""
    if "compared" in record:
        return {int(k): (float(d), float(e)) for k, d, e in
                zip(record["compared"], record["differences"], record["errors"], strict=True)}
    return {2: (float(record["difference"]), float(record.get("se", 0.0)))}


@dataclass(frozen=True)
class ReachRule:
    """Where one later goto setting is taken: on bodies whose reach ``l / r`` lies
    ``above`` (or ``below``) ``threshold``. :meth:`fit` takes, among the thresholds whose
    summed paired gain over the swept designs is within one standard error of the best,
    the one that takes the setting on the fewest bodies (the one-standard-error rule)."""

    setting: int  #: the setting's number in its layout (2: the ``goto2_*`` fields' goto)
    side: str  #: ``above`` or ``below``
    threshold: float  #: the reach where it changes over
    designs: np.ndarray  #: (N, 4) swept designs, m
    differences: np.ndarray  #: (N,) mean paired difference of each (this setting − the first)
    errors: np.ndarray  #: (N,) its standard error

    @classmethod
    def fit(cls, setting: int, side: str, designs: np.ndarray, differences: np.ndarray,
            errors: np.ndarray) -> ReachRule:
        if side not in ("above", "below"):
            raise TrainingError(f"a reach rule's side is above or below, not {side!r}")
        if len(designs) < 5:
            raise TrainingError(f"a goto choice needs at least 5 swept designs for setting {setting}, "
                                f"not {len(designs)}")
        sign = 1.0 if side == "above" else -1.0  # below t on the reach is above -t on its negative
        ratios = sign * reach(designs)
        order = np.argsort(ratios)
        ratios, gains, variances = ratios[order], differences[order], errors[order] ** 2
        # threshold k: just below design k in this order (k = N: the setting nowhere)
        candidates = np.append((np.append(ratios[0] - 1e-6, ratios[:-1]) + ratios) / 2, ratios[-1] + 1e-6)
        if side == "above":
            candidates[0] = 0.0  # every design (reach is positive): as the files before the side was recorded
        totals = np.append(np.cumsum(gains[::-1])[::-1], 0.0)  # gain summed over designs past each
        best = int(np.argmax(totals))
        chosen = best
        for k in range(best + 1, len(candidates)):
            lost = totals[best] - totals[k]
            if lost <= float(np.sqrt(variances[best:k].sum())):
                chosen = k
        return cls(setting, side, float(sign * candidates[chosen]), designs, differences, errors)

    def takes(self, ratio: float) -> bool:
        """Whether a body of reach ``ratio`` gets this setting."""
        return ratio > self.threshold if self.side == "above" else ratio < self.threshold

    def summary(self, task: str) -> str:
        taken = np.array([self.takes(r) for r in reach(self.designs)], dtype=bool)

        def mean(where: np.ndarray) -> str:
            return f"{self.differences[where].mean():+.4f}" if where.any() else "none"

        return (f"setting {self.setting} where l/r {'>' if self.side == 'above' else '<'} {self.threshold:.3f}: "
                f"{taken.sum()} of {len(taken)} swept {task} designs, mean paired difference there {mean(taken)}, "
                f"elsewhere {mean(~taken)}")

    def as_dict(self) -> dict[str, Any]:
        return {"setting": self.setting, "side": self.side, "threshold": self.threshold,
                "designs": self.designs.tolist(), "differences": self.differences.tolist(),
                "errors": self.errors.tolist()}


@dataclass(frozen=True)
class GotoChoice:
    """Which of a layout's goto settings suits a body: the first, unless a
    :class:`ReachRule` takes a later one (``below`` rules before ``above`` ones). The
    sweeps show ``DUAL_GOTO``'s tighter turning losing only on bodies whose legs barely
    tumble them, so one threshold on the reach is its model; ``tri-plan``'s third setting
    gains only on those, below a second threshold."""

    rules: tuple[ReachRule, ...]
    layout: str = "dual"  #: the policy layout whose goto settings it chooses among
    task: str = "nav-flat"  #: the task the sweep drove

    @property
    def settings(self) -> tuple[dict[str, Any], ...]:
        """The layout's goto settings (:data:`~tumblebot.sim.observation.GOTO_SETTINGS`)."""
        return GOTO_SETTINGS[self.layout]

    @property
    def threshold(self) -> float:
        """The second setting's threshold (l / r above which it is taken)."""
        return self._rule(2).threshold

    @property
    def designs(self) -> np.ndarray:
        return self._rule(2).designs

    @property
    def differences(self) -> np.ndarray:
        return self._rule(2).differences

    @property
    def errors(self) -> np.ndarray:
        return self._rule(2).errors

    def _rule(self, setting: int) -> ReachRule:
        return next(rule for rule in self.rules if rule.setting == setting)

    def setting_for(self, design: Sequence[float] | np.ndarray) -> int:
        """The number of the setting (1: the first) that suits ``design``."""
        ratio = float(reach(design)[0])
        for rule in sorted(self.rules, key=lambda rule: rule.side != "below"):
            if rule.takes(ratio):
                return rule.setting
        return 1

    def chosen(self, design: Sequence[float] | np.ndarray) -> dict[str, Any]:
        """The goto settings that suit ``design``."""
        return self.settings[self.setting_for(design) - 1]

    def prefers_dual(self, design: Sequence[float] | np.ndarray) -> bool:
        return self.setting_for(design) == 2

    @classmethod
    def fit(cls, records: Sequence[dict[str, Any]], layout: str | None = None) -> GotoChoice:
        """The choice for ``layout`` (default: the one layout the records were swept for)
        fitted to sweep records. Records of another layout count where they compared the
        same pair of settings (a ``dual-plan`` sweep's second setting is ``tri-plan``'s)."""
        tasks = {r.get("task", "nav-flat") for r in records}  # sweeps before nav-terrain ones were of nav-flat
        if len(tasks) > 1:
            raise TrainingError(f"the sweep mixes the tasks {', '.join(sorted(tasks))}")
        swept = {r.get("layout", "dual") for r in records}  # sweeps before dual-plan were of dual
        if layout is None:
            if len(swept) > 1:
                raise TrainingError(f"the sweep mixes the goto settings of {', '.join(sorted(swept))} "
                                    "(name the layout to fit with --layout)")
            layout = swept.pop() if swept else "dual"
        check_layout(layout)
        settings = GOTO_SETTINGS[layout]
        found: dict[int, list[tuple[list[float], float, float]]] = {k: [] for k in SIDES[layout]}
        for record in records:
            theirs = GOTO_SETTINGS[check_layout(record.get("layout", "dual"))]
            if theirs[0] != settings[0]:
                raise TrainingError(f"a {record.get('layout', 'dual')} sweep compares other goto settings than "
                                    f"the {layout} layout's")
            for number, (difference, error) in comparisons(record).items():
                if number <= len(theirs):
                    matches = [k for k in found if settings[k - 1] == theirs[number - 1]]
                    for k in matches:
                        found[k].append((record["design"], difference, error))
        rules = []
        for k, side in SIDES[layout].items():
            rows = found[k]
            rules.append(ReachRule.fit(k, side, np.array([r[0] for r in rows], dtype=float).reshape(-1, 4),
                                       np.array([r[1] for r in rows], dtype=float),
                                       np.array([r[2] for r in rows], dtype=float)))
        return cls(tuple(rules), layout, tasks.pop() if tasks else "nav-flat")

    def summary(self) -> str:
        return "; ".join(rule.summary(self.task) for rule in self.rules)

    def to_json(self) -> str:
        return json.dumps({"format": FORMAT, "layout": self.layout, "task": self.task, "settings": list(self.settings),
                           "rules": [rule.as_dict() for rule in self.rules]}, indent=1) + "\n"

    @classmethod
    def load(cls, path: Path) -> GotoChoice:
        try:
            data = json.loads(Path(path).read_text())
            layout = data.get("layout", "dual")  # files before dual-plan were of dual
            task = data.get("task", "nav-flat")  # ... and before nav-terrain of nav-flat
            if task not in NAVIGATION_TASKS:
                raise ValueError(f"task {task!r} is not one of {', '.join(NAVIGATION_TASKS)}")
            if layout not in CHOICE_LAYOUTS:
                raise ValueError(f"layout {layout!r} is not one of {', '.join(CHOICE_LAYOUTS)}")
            if data.get("format") == FORMAT_ONE_RULE:  # one threshold, the second setting above it
                if [data.get("first"), data.get("second")] != list(GOTO_SETTINGS[layout]):
                    raise ValueError(f"not a {FORMAT_ONE_RULE} file for the pinned goto settings")
                rules = [{"setting": 2, "side": "above", **{k: data[k] for k in
                                                            ("threshold", "designs", "differences", "errors")}}]
            elif data.get("format") == FORMAT and data.get("settings") == list(GOTO_SETTINGS[layout]):
                rules = data["rules"]
            else:
                raise ValueError(f"not a {FORMAT} file for the pinned goto settings")
            if sorted((r["setting"], r["side"]) for r in rules) != sorted(SIDES[layout].items()):
                raise ValueError(f"its rules are not one for each of the {layout} layout's later settings")
            choice = cls(tuple(ReachRule(int(r["setting"]), str(r["side"]), float(r["threshold"]),
                                         np.array(r["designs"], dtype=float).reshape(-1, 4),
                                         np.array(r["differences"], dtype=float),
                                         np.array(r["errors"], dtype=float)) for r in rules), layout, task)
        except (OSError, json.JSONDecodeError, AttributeError, KeyError, TypeError, ValueError) as exc:
            raise TrainingError(f"goto choice {path}: {exc}") from None
        for rule in choice.rules:
            if not len(rule.designs) == len(rule.differences) == len(rule.errors) or not np.isfinite(rule.threshold):
                raise TrainingError(f"goto choice {path}: inconsistent designs, differences, errors or threshold")
        return choice
