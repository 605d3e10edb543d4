"""Thesis recipe against the efficient recipe, on the same task and episode seeds.

Run: ``.venv/bin/python benchmarks/bench_optimize.py [--seeds 3] [--designs 24] [--workers 2]``

The thesis recipe evaluates every design on the full batch ``B`` (half the designs random,
half by GP-EI). The full thesis schedule (2000 designs × 240 episodes = 480 000 episodes
per study) takes about 9 hours of both cores here per seed, so this benchmark scales it
down to ``--designs`` designs with the thesis's ``B`` and random/EI split, and gives the
efficient recipe ``--fraction`` (10 %) of the episodes that run spent.

For each seed both recipes run in fresh SQLite studies with the same episode seeds. Their
final designs (and the thesis recipe's, which is the reference) are then re-evaluated on
``--final-episodes`` fresh episodes (a seed neither run used), and compared by a paired
t-test (common random numbers). The "best design known" is the best of all final designs
of all runs on that fresh evaluation; the objective gap of each run to it is printed.

The target (issue #4): the efficient recipe's design statistically tied (p > 0.05) with the
thesis recipe's final design, using at most 10 % of its episodes.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.optimize import (
    Objective,
    Recipe,
    StudyConfig,
    best_candidate,
    episode_count,
    open_storage,
    open_study,
    optimize,
)
from tumblebot.sim.policy import bundled_policy
from tumblebot.sim.power import energy_per_metre
from tumblebot.sim.report import paired_p
from tumblebot.sim.runner import EpisodeRunner


def run_recipe(objective: Objective, recipe: Recipe, seed: int, runner: EpisodeRunner, folder: Path,
               budget: int | None = None) -> dict[str, object]:
    storage = open_storage(f"sqlite:///{folder / f'{recipe.name}-{seed}.db'}")
    study = open_study(storage, f"{recipe.name}-{seed}", StudyConfig.of(objective, recipe, seed, {}))
    t0 = time.perf_counter()
    optimize(study, objective, recipe, runner, seed, episode_budget=budget)
    best = best_candidate(study)
    assert best is not None
    return {"recipe": recipe.name, "seed": seed, "episodes": episode_count(study), "trials": len(study.trials),
            "design": best.design, "study_value": best.value, "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="nav-flat")
    ap.add_argument("--xi", type=float, default=3.0)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--designs", type=int, default=32, help="designs in the scaled thesis recipe")
    ap.add_argument("--screen", type=int, default=4, help="efficient: screening episodes per design")
    ap.add_argument("--startup", type=int, default=20, help="efficient: random designs before the GP")
    ap.add_argument("--final-promotions", type=int, default=1,
                    help="efficient: designs given the full batch at the end (each costs B - screen episodes)")
    ap.add_argument("--batch", type=int, default=240, help="full batch B (thesis: 240)")
    ap.add_argument("--fraction", type=float, default=0.10, help="efficient budget as a fraction of the thesis run's")
    ap.add_argument("--final-episodes", type=int, default=240)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", type=Path, default=Path("benchmarks/results/optimize.json"))
    ap.add_argument("--reanalyze", action="store_true",
                    help="re-evaluate the final designs recorded in --json (no optimisation) and print paired and "
                         "Welch tests")
    args = ap.parse_args()
    if args.reanalyze:
        reanalyze(args)
        return

    objective = Objective({args.task: 1.0}, args.xi)
    thesis = Recipe("thesis-scaled", args.designs, args.batch, args.designs // 2, args.batch)
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp, EpisodeRunner({args.task: bundled_policy(args.task)},
                                                             workers=args.workers) as runner:
        for seed in range(args.seeds):
            ref = run_recipe(objective, thesis, seed, runner, Path(tmp))
            budget = int(args.fraction * int(ref["episodes"]))  # type: ignore[call-overload]
            efficient = Recipe("efficient", 100_000, args.batch, args.startup, args.screen, promote_every=0,
                               final_promotions=args.final_promotions)
            eff = run_recipe(objective, efficient, seed, runner, Path(tmp), budget=budget)
            fresh = 10_000 + seed  # episodes neither run has seen
            scores = {}
            for r in (ref, eff):
                R = runner.run(r["design"], [args.task], 0, args.final_episodes, fresh)  # type: ignore[arg-type]
                per = objective.per_episode(R, energy_per_metre(r["design"]))  # type: ignore[arg-type]
                scores[r["recipe"]] = per
                r["fresh_objective"] = float(np.mean(per))
                r["fresh_R"] = float(np.mean(R[args.task]))
            p = paired_p(scores["efficient"], scores["thesis-scaled"])
            rows.append({"seed": seed, "thesis": ref, "efficient": eff, "p_efficient_vs_thesis": p,
                         "episode_ratio": int(eff["episodes"]) / int(ref["episodes"])})  # type: ignore[call-overload]
            print(f"seed {seed}: thesis-scaled {ref['episodes']} episodes → {ref['design']} "
                  f"objective {ref['fresh_objective']:.5f} (R {ref['fresh_R']:.3f}); efficient {eff['episodes']} "
                  f"episodes ({rows[-1]['episode_ratio']:.1%}) → {eff['design']} objective "
                  f"{eff['fresh_objective']:.5f} (R {eff['fresh_R']:.3f}); paired p = {p:.3g}", flush=True)
    best_known = max(max(r["thesis"]["fresh_objective"], r["efficient"]["fresh_objective"]) for r in rows)
    print(f"\nbest design known (fresh evaluation): objective {best_known:.5f}")
    print("seed  recipe         episodes  gap to best known  p vs thesis-scaled")
    for row in rows:
        for name in ("thesis", "efficient"):
            entry_ = row[name]
            shown = "" if name == "thesis" else f"{row['p_efficient_vs_thesis']:.3g}"
            gap = best_known - entry_["fresh_objective"]
            print(f"{row['seed']:>4}  {entry_['recipe']:<13} {entry_['episodes']:>9}  {gap:>17.5f}  {shown}")
    tied = sum(row["p_efficient_vs_thesis"] is None or row["p_efficient_vs_thesis"] > 0.05 for row in rows)
    ratios = [row["episode_ratio"] for row in rows]
    print(f"\nefficient/thesis episodes: {np.mean(ratios):.3f} (mean over seeds); tied (p > 0.05) in {tied} of "
          f"{len(rows)} seeds; efficient better on the fresh evaluation in "
          f"{sum(r['efficient']['fresh_objective'] > r['thesis']['fresh_objective'] for r in rows)} of {len(rows)}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    out = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.node()} ({platform.processor() or 'cpu'})",
           "args": {k: str(v) for k, v in vars(args).items()}, "best_known": best_known,
           "rows": [{**r, "thesis": {**r["thesis"], "design": r["thesis"]["design"].as_tuple()},
                     "efficient": {**r["efficient"], "design": r["efficient"]["design"].as_tuple()}} for r in rows]}
    args.json.write_text(json.dumps(out, indent=2, default=lambda o: None if isinstance(o, float) and
                                    not math.isfinite(o) else str(o)) + "\n")
    print(f"wrote {args.json}")


def reanalyze(args: argparse.Namespace) -> None:
    """Fresh evaluation of recorded final designs: paired (CRN) and Welch t-tests."""
    from scipy import stats

    from tumblebot.sim.design import Design

    data = json.loads(args.json.read_text())
    objective = Objective({args.task: 1.0}, args.xi)
    with EpisodeRunner({args.task: bundled_policy(args.task)}, workers=args.workers) as runner:
        rows = []
        for r in data["rows"]:
            scores = {}
            for name in ("thesis", "efficient"):
                w = Design(*r[name]["design"])
                R = runner.run(w, [args.task], 0, args.final_episodes, 20_000 + r["seed"])
                scores[name] = objective.per_episode(R, energy_per_metre(w))
            paired = paired_p(scores["efficient"], scores["thesis"])
            welch = float(stats.ttest_ind(scores["efficient"], scores["thesis"], equal_var=False).pvalue)
            rows.append((r["seed"], r["thesis"]["episodes"], r["efficient"]["episodes"], scores, paired, welch))
    print("seed  thesis-scaled (episodes, objective)  efficient (episodes, objective)  paired p  Welch p")
    for seed, te, ee, sc, paired, welch in rows:
        print(f"{seed:>4}  {te:>8} {np.mean(sc['thesis']):.5f}               {ee:>6} {np.mean(sc['efficient']):.5f}"
              f"                {paired:.3g}   {welch:.3g}")
    data["reanalysis"] = [{"seed": seed, "thesis_objective": float(np.mean(sc["thesis"])),
                           "efficient_objective": float(np.mean(sc["efficient"])), "paired_p": paired,
                           "welch_p": welch} for seed, _, _, sc, paired, welch in rows]
    args.json.write_text(json.dumps(data, indent=2) + "\n")


if __name__ == "__main__":
    main()
