"""The efficient recipe against a thesis-style reference study, on the same task and episodes.

Run: ``.venv/bin/python benchmarks/bench_optimize.py [--seeds 5] [--designs 124] [--workers 2]``

The reference is the thesis's acquisition scaled down: ``--designs`` trials (half drawn at
random, half by Optuna's GP-EI), every design on the full batch ``B = 240`` (the full
schedule, 2000 designs, is 480 000 episodes: about 9 hours of both cores here). It lives in
``--reference-storage`` and is reused (and resumed, if unfinished) by later runs, since it
is the expensive part: ~30 min on 2 cores. ``--fresh-reference`` runs a new one. Every study
is driven by ``--policy``, by default the policy the committed reference was made with
(``benchmarks/results/optimize-reference-nav-flat.onnx``), so the reference stays valid
when the bundled policy changes.

Then, for each of ``--seeds`` seeds, the efficient recipe runs in a fresh SQLite study with
``--fraction`` (5 %) of the reference's episodes: designs screened on ``--screen`` episodes,
chosen by the GP on ``R`` with ``e(w)`` exact (:mod:`tumblebot.sim.optimize.surrogate`), and
the design of best posterior objective promoted to the full batch at the end.

The reference's optimum and every seed's optimum are re-evaluated on ``--final-episodes``
fresh episodes (a seed no study used; the same episodes for every design), and each seed is
compared with the reference by a paired t-test. The target (optimiser issue, item 4): the
efficient recipe ties (p > 0.05) or beats the reference in at least 4 of 5 seeds at ≤ 5 %
of its episodes.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot import jsonio
from tumblebot.sim.control.drivers import Driver
from tumblebot.sim.control.policy import bundled_policy, sha256_of
from tumblebot.sim.evaluation.runner import EpisodeRunner
from tumblebot.sim.optimize import (
    Objective,
    Recipe,
    StudyConfig,
    TrialRecord,
    best_candidate,
    counted_trials,
    episode_count,
    open_storage,
    open_study,
    optimize,
)
from tumblebot.sim.report import paired_p
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.power import energy_per_metre

#: Seed of the fresh episodes every final design is re-evaluated on (no study uses it).
FRESH_SEED = 10_000


#: The policy the committed reference study was made with (the nav-flat policy bundled on
#: 2026-12-01), so the reference is reused, not redone, whatever policy is bundled today.
REFERENCE_POLICY = Path(__file__).parent / "results" / "optimize-reference-nav-flat.onnx"


def study_config(objective: Objective, recipe: Recipe, seed: int, policy: Path | None = None) -> StudyConfig:
    """What ``tumblebot optimize`` records for this objective with the bundled policies (or
    with ``policy`` driving the one task)."""
    files = {t: policy or bundled_policy(t) for t in objective.tasks}
    return StudyConfig.of(objective, recipe, seed, {t: sha256_of(f) for t, f in files.items()})


def run_recipe(objective: Objective, recipe: Recipe, seed: int, runner: EpisodeRunner | None, url: str, name: str,
               budget: int | None = None, policy: Path | None = None) -> dict[str, Any]:
    """Run (or resume) a study to its end; its optimum, episodes and wall time."""
    storage = open_storage(url)
    study = open_study(storage, name, study_config(objective, recipe, seed, policy))
    t0 = time.perf_counter()
    optimize(study, objective, recipe, runner, seed, episode_budget=budget)
    best = best_candidate(study)
    if best is None:
        raise SystemExit(f"study {name} in {url} has no design on the full batch")
    feasible = sum(TrialRecord.of(t).infeasible is None and t.value is not None for t in study.trials)
    return {"recipe": recipe.name, "seed": seed, "episodes": episode_count(study), "trials": counted_trials(study),
            "feasible_designs": feasible, "design": best.design.as_tuple(), "study_value": best.value,
            "seconds": time.perf_counter() - t0}


def fresh_scores(objective: Objective, runner: EpisodeRunner | None, design: tuple[float, ...], episodes: int,
                 cache: dict[tuple[float, ...], np.ndarray]) -> np.ndarray:
    """The per-episode objective of ``design`` on the fresh episodes (cached by design)."""
    if design not in cache:
        w = Design.from_sequence(design)
        R = runner.run(w, objective.tasks, 0, episodes, FRESH_SEED) if runner is not None and objective.tasks else {}
        cache[design] = np.asarray(objective.per_episode(R, energy_per_metre(w)))
    return cache[design]


def verdict(p: float | None, mine: float, theirs: float) -> str:
    if mine > theirs:
        return "better" if p is not None and p < 0.05 else "tied (ahead)"
    return "tied" if p is None or p > 0.05 else "worse"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="nav-flat")
    ap.add_argument("--xi", type=float, default=3.0)
    ap.add_argument("--seeds", type=int, default=5, help="seeds of the efficient recipe")
    ap.add_argument("--designs", type=int, default=124,
                    help="trials of the reference (infeasible ones cost nothing; 124 gave 102 feasible designs)")
    ap.add_argument("--batch", type=int, default=240, help="full batch B (thesis: 240)")
    ap.add_argument("--screen", type=int, default=4, help="efficient: screening episodes per design")
    ap.add_argument("--startup", type=int, default=20, help="efficient: random designs before the GP")
    ap.add_argument("--fraction", type=float, default=0.05, help="efficient budget as a fraction of the reference's")
    ap.add_argument("--final-episodes", type=int, default=480)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--reference-storage", default="sqlite:///benchmarks/results/optimize-reference.db")
    ap.add_argument("--fresh-reference", action="store_true", help="run a new reference study (a new name)")
    ap.add_argument("--json", type=Path, default=Path("benchmarks/results/optimize.json"))
    ap.add_argument("--policy", type=Path, default=REFERENCE_POLICY,
                    help="the ONNX policy that drives every study's episodes (default: the one the committed "
                         "reference was made with; --fresh-reference with the bundled one: "
                         "--policy policies/nav-flat.onnx)")
    args = _checked(ap.parse_args())

    objective = Objective({args.task: 1.0}, args.xi)
    reference = Recipe("standard", args.designs, args.batch, args.designs // 2, args.batch)
    ref_name = f"reference-{args.task}-xi{args.xi:g}-{args.designs}" + (
        time.strftime("-%Y%m%d%H%M%S") if args.fresh_reference else "")
    if args.reference_storage.startswith("sqlite:///"):
        Path(args.reference_storage[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    cache: dict[tuple[float, ...], np.ndarray] = {}
    with tempfile.TemporaryDirectory() as tmp, EpisodeRunner({args.task: Driver("onnx", str(args.policy))},
                                                             workers=args.workers) as runner:
        print(f"reference: {args.designs} trials at B = {args.batch} in {args.reference_storage} ({ref_name}) …",
              flush=True)
        ref = run_recipe(objective, reference, 0, runner, args.reference_storage, ref_name, policy=args.policy)
        budget = int(args.fraction * ref["episodes"])
        ref_scores = fresh_scores(objective, runner, ref["design"], args.final_episodes, cache)
        ref["fresh_objective"] = float(np.mean(ref_scores))
        print(f"reference: {ref['feasible_designs']} feasible designs, {ref['episodes']} episodes → "
              f"{_design(ref['design'])}, fresh objective {ref['fresh_objective']:.5f}; efficient budget {budget}",
              flush=True)
        for seed in range(args.seeds):
            efficient = Recipe("efficient", 100_000, args.batch, args.startup, args.screen, promote_every=0,
                               final_promotions=1)
            eff = run_recipe(objective, efficient, seed, runner, f"sqlite:///{Path(tmp) / f'eff-{seed}.db'}",
                             f"efficient-{seed}", budget=budget, policy=args.policy)
            scores = fresh_scores(objective, runner, eff["design"], args.final_episodes, cache)
            eff["fresh_objective"] = float(np.mean(scores))
            p = paired_p(scores, ref_scores)
            eff["p_vs_reference"] = p
            eff["verdict"] = verdict(p, eff["fresh_objective"], ref["fresh_objective"])
            eff["episode_ratio"] = eff["episodes"] / ref["episodes"]
            rows.append(eff)
            print(f"seed {seed}: {eff['episodes']} episodes ({eff['episode_ratio']:.1%}), {eff['trials']} trials → "
                  f"{_design(eff['design'])}, fresh objective {eff['fresh_objective']:.5f}; paired p = "
                  f"{_p(p)}: {eff['verdict']} ({eff['seconds']:.0f} s)", flush=True)
    ok = sum(r["verdict"] != "worse" for r in rows)
    print(f"\n{'seed':>4}  {'episodes':>8}  {'share':>6}  design (x, y, z, l)            fresh objective  "
          "p vs reference")
    print(f"{'ref':>4}  {ref['episodes']:>8}  {'100%':>6}  {_design(ref['design'])}  {ref['fresh_objective']:.5f}")
    for r in rows:
        print(f"{r['seed']:>4}  {r['episodes']:>8}  {r['episode_ratio']:>6.1%}  {_design(r['design'])}  "
              f"{r['fresh_objective']:.5f}          {_p(r['p_vs_reference'])} ({r['verdict']})")
    print(f"\nefficient at ≤ {args.fraction:.0%} of the reference's episodes tied or beat it in {ok} of {len(rows)} "
          f"seeds (target: 4 of 5)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    out = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.node()} ({platform.machine()}, "
           f"{platform.processor() or 'cpu'})", "args": {k: str(v) for k, v in vars(args).items()},
           "reference": ref, "efficient": rows, "tied_or_better": ok}
    args.json.write_text(jsonio.dumps(out) + "\n")
    print(f"wrote {args.json}")


def _checked(args: argparse.Namespace) -> argparse.Namespace:
    if args.task != "nav-flat" and args.policy == REFERENCE_POLICY:
        raise SystemExit(f"--task {args.task}: give --policy (the default drives nav-flat)")
    return args


def _design(w: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in w) + ")"


def _p(p: float | None) -> str:
    return "n/a" if p is None else f"{p:.3g}"


if __name__ == "__main__":
    main()
