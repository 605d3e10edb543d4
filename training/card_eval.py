"""The evaluation a model card records: the policy against scripted gaits and a random
policy, on the thesis's ξ = 3 robot and on a design drawn from the bounds; for the
navigation tasks also against every hand-written navigation controller (``goto``,
``plan``, ``plan-short``), paired on the same episodes, on two sets of designs: a fixed one
(:data:`NAV_GRID` for ``nav-flat``, the two card designs for ``nav-terrain``) and designs
drawn afresh from the bounds with :data:`FRESH_DESIGN_SEED`, a seed no training run uses,
so that a policy cannot be tuned to the designs it is judged on. A design where the policy
falls behind is measured again on fresh episodes before the card says so."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from tumblebot.sim.control.gaits import GAITS
from tumblebot.sim.control.goto import NAVIGATION_TASKS, NAVIGATORS
from tumblebot.sim.control.policy import card_path
from tumblebot.sim.evaluation.evaluate import Driver, EvalResult, evaluate_with, run_lanes
from tumblebot.sim.evaluation.runner import EpisodeRunner
from tumblebot.sim.evaluation.stats import paired_p
from tumblebot.sim.world.design import THESIS_ROBOTS, Design, tumbling_designs
from tumblebot.sim.world.physics import THESIS, PhysicsProfile
from tumblebot.sim.world.tasks import get_task

XI3_ROBOT = THESIS_ROBOTS["3"]


#: The random design of the model cards, (0.258, 0.107, 0.113, 0.155): the first draw of seed
#: 2021 that can tumble (the very first, (0.273, 0.241, 0.153, 0.125), cannot, so every
#: controller would score the same there and the comparison would say nothing).
RANDOM_DESIGN = tumbling_designs(1, 2021)[0]
FIXED_GAITS = [g for g in GAITS if g not in ("random", "excite")]  # excite identifies, it does not navigate


def _grid() -> dict[str, Design]:
    """Twelve designs that can tumble, spread over the bounds: three body sizes (small,
    medium, large side profile), each with a short, medium and long leg, at three widths;
    then the thesis's ξ = 0, 3 and ∞ robots."""
    bodies = {"small": (0.110, 0.090), "medium": (0.160, 0.130), "large": (0.220, 0.180)}
    legs = {"small": (0.090, 0.150, 0.240), "medium": (0.120, 0.180, 0.240), "large": (0.160, 0.200, 0.250)}
    widths = (0.190, 0.245, 0.300)
    grid: dict[str, Design] = {}
    for b, (y, z) in bodies.items():
        for k, (leg, x) in enumerate(zip(legs[b], widths if b != "medium" else widths[::-1], strict=True)):
            grid[f"{b} body, {('short', 'medium', 'long')[k]} legs"] = Design(x, y, z, leg)
    for xi in ("0", "3", "inf"):
        grid[f"thesis ξ = {'∞' if xi == 'inf' else xi} robot"] = THESIS_ROBOTS[xi]
    assert all(d.can_tumble for d in grid.values())
    return grid


#: The design grid of the navigation cards (the bar: no more than 0.02 behind the strongest
#: hand-written controller wherever it reaches 0.5, and ahead of it on average).
NAV_GRID: dict[str, Design] = _grid()


#: The seed of the card's fresh designs (the 10 000th prime; training draws its designs
#: from the run's seed, the choice sweeps from theirs, and no run uses this one).
FRESH_DESIGN_SEED = 104729
#: How many fresh designs a card draws, and the most episodes it runs on each.
FRESH_DESIGNS = {"nav-flat": 24, "nav-terrain": 8}
FRESH_EPISODES = 48
#: The bar: on every design where the strongest hand-written controller reaches
#: :data:`WORKS`, the policy is no more than :data:`TOLERANCE` behind it, and it is ahead on average.
WORKS = 0.5
TOLERANCE = 0.02
#: A design the first measurement puts behind is measured again on fresh episodes (seed +
#: :data:`CONFIRM_SEED_OFFSET`, five times as many, at most :data:`CONFIRM_EPISODES`) before
#: the card calls it behind: the strongest of three controllers on 48 episodes is picked
#: for its luck as much as for its skill, so a policy level with it falls behind by chance
#: on some designs (as ``benchmarks/bench_fresh_designs.py`` confirms its failures).
CONFIRM_EPISODES = 240
CONFIRM_SEED_OFFSET = 1000


def fresh_designs(task: str, seed: int = FRESH_DESIGN_SEED) -> dict[str, Design]:
    """The card's designs drawn afresh for ``task``: uniform over the bounds, legs that tumble the body."""
    return {f"fresh {k + 1}": d for k, d in enumerate(tumbling_designs(FRESH_DESIGNS[task], seed))}


POLICY = "policy"  #: the card runner's lane of the policy; a gait's is "gait:NAME", a navigator's "nav:NAME"


def card_runner(policy: Path, task: str, workers: int, physics: PhysicsProfile = THESIS) -> EpisodeRunner:
    """One pool for all of a card's episodes: the policy, every gait and, on a navigation
    task, every hand-written navigator, side by side (lanes :data:`POLICY`, ``gait:NAME``, ``nav:NAME``)."""
    lanes: dict[str, Path | str | Driver] = {POLICY: Driver("onnx", str(policy))}
    lanes |= {f"gait:{g}": Driver("gait", g) for g in [*FIXED_GAITS, "random"]}
    if get_task(task).name in NAVIGATION_TASKS:
        lanes |= {f"nav:{n}": Driver("goto", n) for n in NAVIGATORS}
    return EpisodeRunner(lanes, workers=workers, physics=physics, task=task)


def _compare(runner: EpisodeRunner, label: str, design: Design, episodes: int, seed: int,
             pol: np.ndarray | None = None) -> dict[str, Any]:
    """One design's row: the policy (``pol``, its R if already measured on these episodes)
    and every hand-written controller on the same episodes."""
    lanes = ([] if pol is not None else [POLICY]) + [f"nav:{n}" for n in NAVIGATORS]
    R = {k: r for k, (r, _) in run_lanes(runner, design, lanes, episodes, seed, f"compare on {label}").items()}
    policy = pol if pol is not None else R[POLICY]
    hand = {name: R[f"nav:{name}"] for name in NAVIGATORS}
    means = {name: float(np.mean(r)) for name, r in hand.items()}
    strongest = max(hand, key=lambda name: means[name])
    mean = float(np.mean(policy))
    return {"label": label, "design": design.as_dict(), "policy_mean_R": mean,
            "hand_written": {name: {"mean_R": means[name], "difference": mean - means[name],
                                    "p_paired": paired_p(policy, r)} for name, r in hand.items()},
            "strongest": strongest, "difference": mean - means[strongest],
            "p_paired": paired_p(policy, hand[strongest])}


def _works(row: dict[str, Any]) -> bool:
    """Whether the row's strongest hand-written controller reaches :data:`WORKS`: the bar holds there."""
    return bool(row["hand_written"][row["strongest"]]["mean_R"] >= WORKS)


def behind(strongest_mean_R: float, difference: float) -> bool:
    """The bar's test on one design: the strongest hand-written controller reaches
    :data:`WORKS` there and the policy trails it by more than :data:`TOLERANCE`."""
    return strongest_mean_R >= WORKS and difference < -TOLERANCE


def _is_behind(row: dict[str, Any]) -> bool:
    """Whether the policy is :func:`behind` on the row's design."""
    return behind(row["hand_written"][row["strongest"]]["mean_R"], row["difference"])


def hand_written_comparison(runner: EpisodeRunner, designs: dict[str, Design], episodes: int, seed: int,
                            known: dict[Design, EvalResult] | None = None, confirm: int = 0) -> dict[str, Any]:
    """The policy against each hand-written navigation controller (:data:`NAVIGATORS`) on
    each design, on the same episodes (``runner``: a :func:`card_runner`); a table's rows
    and the bar's verdict. ``known`` holds the policy's results already measured on these
    episodes, by design. With
    ``confirm`` > 0, a design found behind is measured again on that many fresh episodes
    (seed + :data:`CONFIRM_SEED_OFFSET`; the row's ``confirmation``), and is behind only if
    it is behind there too (``screened_behind`` lists those found behind first)."""
    known = known or {}
    rows = [_compare(runner, label, design, episodes, seed, known[design].R if design in known else None)
            for label, design in designs.items()]
    where_it_works = [r for r in rows if _works(r)]
    screened = [r["label"] for r in rows if _is_behind(r)]
    behind = list(screened)
    if confirm > 0:
        for row in (r for r in rows if r["label"] in screened):
            again = _compare(runner, row["label"], designs[row["label"]], confirm, seed + CONFIRM_SEED_OFFSET)
            row["confirmation"] = {"episodes": confirm, "seed": seed + CONFIRM_SEED_OFFSET,
                                   **{k: again[k] for k in ("policy_mean_R", "hand_written", "strongest",
                                                            "difference", "p_paired")}}
            if not _is_behind(again):
                behind.remove(row["label"])
    mean = float(np.mean([r["difference"] for r in rows]))
    return {"episodes_per_design": episodes, "seed": seed, "rows": rows,
            "mean_difference": mean,
            "mean_difference_by_controller": {name: float(np.mean([r["hand_written"][name]["difference"]
                                                                   for r in rows])) for name in NAVIGATORS},
            "worst_difference_where_it_reaches_0.5": (min(r["difference"] for r in where_it_works)
                                                      if where_it_works else None),
            "confirm_episodes": confirm, "screened_behind": screened,
            "behind": behind, "bar_met": not behind and mean > 0}


def comparison_table(comparison: dict[str, Any]) -> str:
    """:func:`hand_written_comparison` as a Markdown table: the policy, each hand-written
    controller, and the policy's difference to the strongest of them with its paired p."""
    names = list(comparison["rows"][0]["hand_written"]) if comparison["rows"] else []
    lines = ["| design | (x, y, z, l) m | policy | " + " | ".join(names) + " | policy − strongest | p (paired) |",
             "|---|---|---|" + "---|" * len(names) + "---|---|"]
    for r in comparison["rows"]:
        d = r["design"]
        marks = (" **behind**" if r["label"] in comparison["behind"] else
                 f" (within the bar on {r['confirmation']['episodes']} fresh episodes)" if "confirmation" in r else "")
        lines.append(f"| {r['label']} | ({d['x']:.3f}, {d['y']:.3f}, {d['z']:.3f}, {d['l']:.3f}) | "
                     f"{r['policy_mean_R']:.3f} | "
                     + " | ".join(f"{r['hand_written'][n]['mean_R']:.3f}" for n in names)
                     + f" | {r['difference']:+.3f}{marks} | {r['p_paired']:.2g} |")
    rows = comparison["rows"]
    lines.append(f"| mean | | {np.mean([r['policy_mean_R'] for r in rows]):.3f} | "
                 + " | ".join(f"{np.mean([r['hand_written'][n]['mean_R'] for r in rows]):.3f}" for n in names)
                 + f" | {comparison['mean_difference']:+.3f} | |")
    return "\n".join(lines) + "\n"


def comparison_summary(comparison: dict[str, Any]) -> str:
    """One line: the mean and worst difference to the strongest hand-written controller and the bar's verdict."""
    worst = comparison["worst_difference_where_it_reaches_0.5"]
    verdict = "met" if comparison["bar_met"] else f"NOT met ({len(comparison['behind'])} behind)"
    screened = comparison.get("screened_behind", comparison["behind"])
    if len(screened) > len(comparison["behind"]):
        verdict += (f"; {len(screened) - len(comparison['behind'])} of the {len(screened)} behind at first "
                    f"within the bar on {comparison['confirm_episodes']} fresh episodes")
    return (f"{len(comparison['rows'])} designs, {comparison['episodes_per_design']} paired episodes each: "
            f"policy − strongest hand-written mean {comparison['mean_difference']:+.3f}, worst "
            f"{'n/a' if worst is None else f'{worst:+.3f}'} where it reaches {WORKS}; bar {verdict}")


def _welch(a: EvalResult, b: EvalResult) -> float:
    """One-sided p-value that ``a`` has a higher mean R than ``b`` (Welch's t-test)."""
    return float(stats.ttest_ind(a.R, b.R, equal_var=False, alternative="greater").pvalue)


def _welch_from_summary(a: EvalResult, b: dict[str, Any], n: int) -> float:
    """:func:`_welch` against a recorded baseline (mean and 95 % t interval of ``n`` episodes)."""
    half = (b["ci95"][1] - b["ci95"][0]) / 2
    sd = half * math.sqrt(n) / float(stats.t.ppf(0.975, n - 1))
    return float(stats.ttest_ind_from_stats(a.mean_R, float(np.std(a.R, ddof=1)), a.episodes, b["mean_R"], sd, n,
                                            equal_var=False, alternative="greater").pvalue)


def _recorded_baselines(runner: EpisodeRunner, previous: dict[str, Any] | None, label: str, design: Design,
                        episodes: int, seed: int) -> dict[str, Any] | None:
    """A previous card's gait baselines for ``label``, if they are for the same design,
    episodes and seed and still reproduce: the gaits do not depend on the policy, so the
    same episodes give the same numbers. Checked by re-running its best fixed gait, which
    must give the recorded mean exactly; else None (everything is re-run)."""
    if previous is None or previous.get("episodes_per_design") != episodes or previous.get("seed") != seed:
        return None
    entry = previous.get("designs", {}).get(label)
    if not entry or entry.get("design") != design.as_dict() or "baselines" not in entry:
        return None
    best = entry["best_fixed_gait"]
    check = evaluate_with(runner, f"gait:{best}", design, episodes, seed, progress=True)
    if check.mean_R != entry["baselines"][best]["mean_R"]:
        return None
    return {"baselines": entry["baselines"], "best_fixed_gait": best}


def _confirm(asked: int | None, episodes: int) -> int:
    """The episodes of a second measurement: ``asked``, or five times ``episodes``, at most :data:`CONFIRM_EPISODES`."""
    return asked if asked is not None else min(CONFIRM_EPISODES, 5 * episodes)


def card_evaluation(policy: Path, task: str, episodes: int, seed: int, workers: int,
                    previous: dict[str, Any] | None = None, confirm: int | None = None) -> dict[str, Any]:
    """The card's evaluation. ``previous``, an earlier card's ``evaluation`` for the same
    task, lends its gait baselines where they still reproduce (see :func:`_recorded_baselines`).
    Every episode runs under the physics profile the policy was trained under (its card's).
    ``confirm``: the episodes a design behind the strongest hand-written controller is
    measured again on (default five times the first measurement's, at most
    :data:`CONFIRM_EPISODES`; 0: none)."""
    physics = PhysicsProfile.from_card(json.loads(card_path(policy).read_text()).get("servo") or {})
    with card_runner(policy, task, workers, physics) as runner:
        return _card_evaluation(runner, task, episodes, seed, previous, confirm)


def _card_evaluation(runner: EpisodeRunner, task: str, episodes: int, seed: int, previous: dict[str, Any] | None,
                     confirm: int | None) -> dict[str, Any]:
    out: dict[str, Any] = {"episodes_per_design": episodes, "seed": seed, "designs": {}}
    measured: dict[Design, EvalResult] = {}
    for label, design in (("xi3_robot", XI3_ROBOT), ("random_design", RANDOM_DESIGN)):
        pol = evaluate_with(runner, POLICY, design, episodes, seed, progress=True)
        measured[design] = pol
        entry = pol.summary()
        recorded = _recorded_baselines(runner, previous, label, design, episodes, seed)
        if recorded is not None:
            entry.update(recorded, baselines_reused_from_previous_card=True)
            base = recorded["baselines"]
            entry["p_vs_best_fixed_gait"] = _welch_from_summary(pol, base[recorded["best_fixed_gait"]], episodes)
            entry["p_vs_random_policy"] = _welch_from_summary(pol, base["random"], episodes)
        else:
            gaits = {g: evaluate_with(runner, f"gait:{g}", design, episodes, seed, progress=True)
                     for g in [*FIXED_GAITS, "random"]}
            best_fixed = max(FIXED_GAITS, key=lambda g: gaits[g].mean_R)
            entry["baselines"] = {g: {"mean_R": r.mean_R, "ci95": list(r.ci95)} for g, r in gaits.items()}
            entry["best_fixed_gait"] = best_fixed
            entry["p_vs_best_fixed_gait"] = _welch(pol, gaits[best_fixed])
            entry["p_vs_random_policy"] = _welch(pol, gaits["random"])
        out["designs"][label] = entry
    if task in NAVIGATION_TASKS:
        # The grid on flat ground; on terrain (six times slower to simulate) the card's two designs.
        designs = NAV_GRID if task == "nav-flat" else {"thesis ξ = 3 robot": XI3_ROBOT, "random design": RANDOM_DESIGN}
        out["against_hand_written"] = {
            "fixed": hand_written_comparison(runner, designs, episodes, seed, measured,
                                             confirm=_confirm(confirm, episodes)),
            "fresh": {"design_seed": FRESH_DESIGN_SEED,
                      **hand_written_comparison(runner, fresh_designs(task), min(episodes, FRESH_EPISODES), seed,
                                                confirm=_confirm(confirm, min(episodes, FRESH_EPISODES)))}}
    return out
