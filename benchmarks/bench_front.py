"""One front study against four per-ξ studies: does it find every ξ's optimum for a third of
their episodes?

Run: ``.venv/bin/python benchmarks/bench_front.py [--budget 1200] [--seeds 1] [--first-seed 0] [--workers 2]``

For each seed, on ``--task`` (nav-flat), the same episodes everywhere (common random numbers):

* four single-ξ studies: ξ = 0, 1 and 3 with the efficient recipe and ``--budget`` episodes
  each, and ξ = ∞ (``e(w)`` alone: Optuna's GP on ``-e``, ``--inf-trials`` designs, no episodes);
* one front study (``optimize --front 0,1,3,inf``, the efficient recipe) with a third of
  the episodes the four spent together.

Every optimum is then re-evaluated on ``--final-episodes`` fresh episodes and, for each ξ,
the front's optimum is compared with the single study's by a paired t-test on the
per-episode objective at that ξ (for ξ = ∞ the objective is ``-e``, exact: the front ties
or beats when its ``e`` is no larger). The target (optimiser issue, item 3): a tie
(p > 0.05) or better at every ξ, at ≤ 1/3 of the four studies' episodes.
"""

from __future__ import annotations

import argparse
import math
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from bench_optimize import FRESH_SEED, _design, _p, run_recipe, study_config, verdict

from tumblebot import jsonio
from tumblebot.sim.control.policy import bundled_policy
from tumblebot.sim.evaluation.runner import EpisodeRunner
from tumblebot.sim.optimize import Objective, Recipe, format_xi, front_optima, open_storage, open_study
from tumblebot.sim.report import paired_p
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.power import energy_per_metre

XIS = (0.0, 1.0, 3.0, math.inf)


def _arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="nav-flat")
    ap.add_argument("--seeds", type=int, default=1, help="how many seeds to run (1)")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="the first of them (0): --first-seed 1 --seeds 1 runs seed 1 alone")
    ap.add_argument("--budget", type=int, default=1200, help="episodes of each finite-ξ study")
    ap.add_argument("--batch", type=int, default=240)
    ap.add_argument("--screen", type=int, default=4)
    ap.add_argument("--startup", type=int, default=20)
    ap.add_argument("--inf-trials", type=int, default=60, help="designs of the ξ = inf study (free: no episodes)")
    ap.add_argument("--final-episodes", type=int, default=480)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--storage", default=None,
                    help="keep the studies in this SQLite folder's files (default: a temporary folder); a rerun "
                         "reuses finished per-ξ studies")
    ap.add_argument("--front-study", default="front", help="name of the front study (a new name reruns only it)")
    ap.add_argument("--json", type=Path, default=Path("benchmarks/results/front.json"))
    args = ap.parse_args()
    if args.seeds < 1 or args.first_seed < 0:
        ap.error("need --seeds ≥ 1 and --first-seed ≥ 0")
    return args


def main() -> None:
    args = _arguments()

    weights = {args.task: 1.0}
    efficient = Recipe("efficient", 100_000, args.batch, args.startup, args.screen, promote_every=0,
                       final_promotions=1)
    out: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp, EpisodeRunner({args.task: bundled_policy(args.task)},
                                                             workers=args.workers) as runner:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            folder = Path(args.storage) if args.storage else Path(tmp)
            folder.mkdir(parents=True, exist_ok=True)
            url = f"sqlite:///{folder / f'front-{seed}.db'}"
            single: dict[float, dict[str, Any]] = {}
            for xi in XIS:
                objective = Objective(weights, xi)
                if math.isinf(xi):
                    recipe = Recipe("standard", args.inf_trials, 1, min(20, args.inf_trials // 2), 1)
                    single[xi] = run_recipe(objective, recipe, seed, None, url, f"xi{format_xi(xi)}")
                else:
                    single[xi] = run_recipe(objective, efficient, seed, runner, url, f"xi{format_xi(xi)}",
                                            budget=args.budget)
                print(f"seed {seed}, ξ = {format_xi(xi)} study: {single[xi]['episodes']} episodes → "
                      f"{_design(single[xi]['design'])}", flush=True)
            spent = sum(r["episodes"] for r in single.values())
            front_objective = Objective(weights, 0.0, front=XIS)
            front = run_recipe(front_objective, efficient, seed, runner, url, args.front_study, budget=spent // 3)
            study = open_study(open_storage(url), args.front_study, study_config(front_objective, efficient, seed))
            optima = front_optima(study, XIS)
            print(f"seed {seed}, front study: {front['episodes']} episodes ({front['episodes'] / spent:.1%} of "
                  f"{spent}) in {front['seconds']:.0f} s", flush=True)
            for xi in XIS:
                objective = Objective(weights, xi)
                mine, theirs = optima[xi].design.as_tuple(), tuple(single[xi]["design"])
                a, b = (_fresh(objective, runner, w, args.final_episodes) for w in (mine, theirs))
                if math.isinf(xi):
                    p: float | None = None  # -e is exact: no test, just the comparison
                    v = "tied" if np.isclose(a[0], b[0]) else ("better" if a[0] > b[0] else "worse")
                else:
                    p = paired_p(a, b)
                    v = verdict(p, float(np.mean(a)), float(np.mean(b)))
                row = {"seed": seed, "xi": format_xi(xi), "front_design": mine, "single_design": theirs,
                       "front_objective": float(np.mean(a)), "single_objective": float(np.mean(b)), "p": p,
                       "verdict": v, "front_episodes": front["episodes"], "single_episodes": spent}
                out.append(row)
                print(f"  ξ = {format_xi(xi):<3}  front {_design(mine)} {row['front_objective']:.5g}  single "
                      f"{_design(theirs)} {row['single_objective']:.5g}  p = {_p(p)}: {v}", flush=True)
    ok = all(r["verdict"] != "worse" for r in out)
    share = max(r["front_episodes"] / r["single_episodes"] for r in out)
    print(f"\nfront study at {share:.1%} (at most) of the four studies' episodes: "
          + ("tied or better at every ξ" if ok else "WORSE at " + ", ".join(
              f"seed {r['seed']} ξ = {r['xi']}" for r in out if r["verdict"] == "worse")))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    record = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.node()} ({platform.machine()})",
              "args": {k: str(v) for k, v in vars(args).items()}, "rows": out, "all_tied_or_better": ok}
    args.json.write_text(jsonio.dumps(record) + "\n")
    print(f"wrote {args.json}")


_CACHE: dict[tuple[str, tuple[float, ...]], np.ndarray] = {}


def _fresh(objective: Objective, runner: EpisodeRunner, design: tuple[float, ...], episodes: int) -> np.ndarray:
    """Per-episode objective at this ξ on the fresh episodes (R cached by design)."""
    w = Design.from_sequence(design)
    key = (",".join(objective.tasks) or "none", design)
    if math.isinf(objective.xi):
        return np.asarray(objective.per_episode({}, energy_per_metre(w)))
    if key not in _CACHE:
        _CACHE[key] = runner.run(w, objective.tasks, 0, episodes, FRESH_SEED)[objective.tasks[0]]
    return np.asarray(objective.per_episode({objective.tasks[0]: _CACHE[key]}, energy_per_metre(w)))


if __name__ == "__main__":
    main()
