"""The bundled navigation policy against every hand-written controller, on designs drawn
afresh: an evaluation that cannot be tuned to.

Run: ``.venv/bin/python benchmarks/bench_fresh_designs.py [--task nav-flat] [--designs 24]
[--design-seed 7919] [--reach-below L/R] [--episodes 48] [--seed 1] [--workers 2] [--hand-written goto,…]
[--confirm 240] [--cross-fit] [--json FILE]``

``--designs`` designs are drawn uniformly from the bounds with ``--design-seed`` (any seed
works: the model cards' grid and training never see it), keeping those whose legs can lift
the body (with ``--reach-below``, only those whose legs reach less than that many pivot
radii: one class of bodies, the same draws filtered). On each, the policy, the hand-
written navigation controllers (``goto``, ``plan`` and ``plan-short``) and every fixed
scripted gait drive the same ``--episodes`` episodes (common random numbers, ``--seed``).
Per design it prints each controller's mean final R, the policy's paired difference to the
strongest hand-written controller on that design, and the paired t-test's p-value; then
the bar the navigation cards hold the policy to: no more than 0.02 behind the strongest
hand-written controller on every design where that controller reaches 0.5, and ahead of it
on average.

With 48 episodes a design's paired difference has a standard error of about 0.02, so a
policy that equals its teacher in expectation falls 0.02 behind on some of 24 designs by
chance. Each design that fails the bar is therefore measured again on ``--confirm``
fresh episodes (seed ``--seed`` + 1000), by the policy and every hand-written
navigation controller; the verdict at ``--episodes`` stands as the bar's, and the
re-measurement is printed beside it.

Taking each design's strongest controller on the very episodes it is compared on favours
that controller: the largest of three noisy means overstates the strongest one's true
mean. ``--cross-fit`` runs every controller on a second set of as many episodes (seed
``--seed`` + 2000) and also prints the difference to the strongest chosen on the *other*
set, both ways round, beside the same-episode one. That estimate errs the other way (a
controller chosen on noisy means is not always the strongest), so the true difference
lies between the two.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot import jsonio
from tumblebot.cliargs import reach_bound
from tumblebot.sim.control.drivers import Driver
from tumblebot.sim.control.gaits import GAITS
from tumblebot.sim.control.goto import NAVIGATION_TASKS, NAVIGATORS
from tumblebot.sim.evaluation.runner import EpisodeRunner
from tumblebot.sim.evaluation.stats import paired_p
from tumblebot.sim.optimize import bundled_policies
from tumblebot.sim.world.design import Design, tumbling_designs
from tumblebot.training.card_eval import CONFIRM_SEED_OFFSET, TOLERANCE, WORKS, behind

CROSS_FIT_SEED_OFFSET = 2000  #: the second set of episodes of --cross-fit: apart from the confirmations' (+1000)
HAND_WRITTEN = [*NAVIGATORS] + [g for g in GAITS if g not in ("random", "excite")]  # excite identifies


def _strongest(R: dict[str, np.ndarray], hand: list[str]) -> str:
    """The controller of ``hand`` with the highest mean final R in ``R`` (episodes by controller)."""
    return max(hand, key=lambda n: float(R[n].mean()))


def cross_fit(first: dict[str, np.ndarray], second: dict[str, np.ndarray], hand: list[str]) -> tuple[float, float]:
    """One design's policy − strongest of ``hand`` from two independent sets of episodes
    (each a controller's final R by episode), averaged over both sets: with the strongest
    taken on the set compared on (the cards' way), and chosen on the other set."""
    same = [float(R["policy"].mean() - R[_strongest(R, hand)].mean()) for R in (first, second)]
    crossed = [float(R["policy"].mean() - R[_strongest(other, hand)].mean())
               for R, other in ((first, second), (second, first))]
    return float(np.mean(same)), float(np.mean(crossed))


def _cross_fit_summary(rows: list[dict[str, Any]], args: argparse.Namespace) -> str:
    """The ``--cross-fit`` line: both estimates' means over the designs, with their standard errors."""
    parts = []
    for key, what in (("policy_minus_strongest_same", "taken on the same episodes"),
                      ("policy_minus_strongest_other", "chosen on the other set")):
        x = np.array([r["cross_fit"][key] for r in rows])
        se = float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")
        parts.append(f"{what} {x.mean():+.4f} ± {se:.4f}")
    return (f"cross-fit over {args.episodes} episodes of seed {args.seed} and of seed "
            f"{args.seed + CROSS_FIT_SEED_OFFSET}: policy − strongest " + ", ".join(parts)
            + " (mean ± standard error over the designs; the true difference lies between the two)")


def _confirm(runner: EpisodeRunner, row: dict[str, Any], args: argparse.Namespace,
             hand: list[str]) -> dict[str, Any]:
    """Row ``row``'s design re-measured on ``args.confirm`` fresh episodes: the policy
    against the strongest of ``hand`` there; printed, and returned for the JSON."""
    design = Design(**row["design"])
    seed = args.seed + CONFIRM_SEED_OFFSET
    R = runner.run(design, ["policy", *hand], 0, args.confirm, seed)
    best = _strongest(R, hand)
    diff = float(R["policy"].mean() - R[best].mean())
    p = paired_p(R["policy"], R[best])
    still = behind(float(R[best].mean()), diff)
    text = "(" + ", ".join(f"{v:.3f}" for v in design.as_tuple()) + ")"
    print(f"  {text}: on {args.confirm} fresh episodes (seed {seed}) policy {float(R['policy'].mean()):.3f}, "
          + ", ".join(f"{n} {float(R[n].mean()):.3f}" for n in hand)
          + f": policy − {best} {diff:+.3f} (p = {p if p is not None else float('nan'):.2g}), "
          + ("still behind" if still else "within the bar"), flush=True)
    return {"episodes": args.confirm, "seed": seed, "mean_R": {n: float(v.mean()) for n, v in R.items()},
            "best_hand_written": best, "policy_minus_best": diff, "p": p, "behind": still}


def _arguments() -> tuple[argparse.Namespace, list[str]]:
    """The command line, checked: the arguments and the hand-written controllers named."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="nav-flat", choices=NAVIGATION_TASKS)
    ap.add_argument("--designs", type=int, default=24, help="fresh designs (24)")
    ap.add_argument("--design-seed", type=int, default=7919, help="seed the designs are drawn with (7919)")
    ap.add_argument("--reach-below", type=reach_bound, default=None, metavar="L/R",
                    help="keep only designs whose legs reach less than this many pivot radii (default all)")
    ap.add_argument("--episodes", type=int, default=48, help="episodes per design and controller (48)")
    ap.add_argument("--seed", type=int, default=1, help="episode seed (1)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--policy", type=Path, help="ONNX policy (default: the task's bundled policy)")
    ap.add_argument("--hand-written", default=",".join(HAND_WRITTEN),
                    help=f"the hand-written controllers to compare with (default all: {','.join(HAND_WRITTEN)})")
    ap.add_argument("--confirm", type=int, default=240,
                    help="re-measure each design that fails the bar on this many fresh episodes (240; 0: do not)")
    ap.add_argument("--cross-fit", action="store_true",
                    help=f"also run every controller on a second set of episodes (seed + {CROSS_FIT_SEED_OFFSET}) and "
                         "compare the policy with the strongest chosen on the other set")
    ap.add_argument("--json", type=Path, help="also write the per-design results here")
    args = ap.parse_args()
    if args.designs < 1 or args.episodes < 2 or args.workers < 1 or args.confirm not in (0, *range(2, 100_001)):
        ap.error("--designs and --workers must be at least 1, --episodes at least 2, --confirm 0 or 2–100000")
    hand = [n for n in args.hand_written.split(",") if n]
    if not hand or any(n not in HAND_WRITTEN for n in hand):
        ap.error(f"--hand-written takes a comma-separated list of {', '.join(HAND_WRITTEN)}")
    return args, hand


def main() -> int:
    args, hand = _arguments()
    policy = args.policy or bundled_policies([args.task])[args.task]
    print(f"bench_fresh_designs {time.strftime('%Y-%m-%d')} on {platform.node()} ({os.cpu_count()} cores, "
          f"{platform.machine()}): {args.task}, policy {policy.name}, {args.designs} designs drawn with seed "
          f"{args.design_seed}" + ("" if args.reach_below is None else f" with l/r below {args.reach_below:g}")
          + f", {args.episodes} paired episodes each (seed {args.seed})", flush=True)
    drivers = {"policy": Driver("onnx", str(policy)), **{name: Driver.of_gait(name) for name in hand}}
    rows: list[dict[str, Any]] = []
    print(f"{'design (x, y, z, l)':<30} {'l/r':>4} " + " ".join(f"{n:>8}" for n in drivers)
          + f" {'best hand':>10} {'policy-best':>11} {'p':>7}")
    runner = EpisodeRunner(drivers, workers=args.workers, task=args.task)  # one pool, every controller side by side
    try:
        for design in tumbling_designs(args.designs, args.design_seed, args.reach_below):
            R = runner.run(design, list(drivers), 0, args.episodes, args.seed)
            best = _strongest(R, hand)
            diff = float(R["policy"].mean() - R[best].mean())
            p = paired_p(R["policy"], R[best])
            fails = behind(float(R[best].mean()), diff)
            rows.append({"design": design.as_dict(), "l_over_r": design.reach,
                         "mean_R": {n: float(v.mean()) for n, v in R.items()}, "best_hand_written": best,
                         "policy_minus_best": diff, "p": p, "fails_bar": fails})
            if args.cross_fit:
                seed2 = args.seed + CROSS_FIT_SEED_OFFSET
                R2 = runner.run(design, list(drivers), 0, args.episodes, seed2)
                same, crossed = cross_fit(R, R2, hand)
                rows[-1]["cross_fit"] = {"seed": seed2, "mean_R": {n: float(v.mean()) for n, v in R2.items()},
                                         "policy_minus_strongest_same": same,
                                         "policy_minus_strongest_other": crossed}
            text = "(" + ", ".join(f"{v:.3f}" for v in design.as_tuple()) + ")"
            print(f"{text:<30} {design.reach:4.2f} "
                  + " ".join(f"{float(R[n].mean()):8.3f}" for n in drivers)
                  + f" {best:>10} {diff:+11.3f} {p if p is not None else float('nan'):7.2g}"
                  + ("  FAILS" if fails else ""), flush=True)
        for row in rows:
            if row["fails_bar"] and args.confirm:
                row["confirm"] = _confirm(runner, row, args, [n for n in hand if n in NAVIGATORS] or hand)
    finally:
        runner.close()
    diffs = np.array([r["policy_minus_best"] for r in rows])
    failed = [r for r in rows if r["fails_bar"]]
    each = "; ".join(f"policy − {n}: mean {np.mean([r['mean_R']['policy'] - r['mean_R'][n] for r in rows]):+.3f}"
                     for n in hand if n in NAVIGATORS)
    print(f"policy − strongest hand-written controller: mean {diffs.mean():+.3f}, worst {diffs.min():+.3f}"
          + (f"; {each}" if each else ""))
    verdict = "met" if not failed and diffs.mean() > 0 else "NOT met"
    print(f"bar (no more than {TOLERANCE} behind wherever the best reaches {WORKS}, ahead on average): {verdict}"
          + (f" ({len(failed)} design{'' if len(failed) == 1 else 's'} behind)" if failed else ""))
    if args.cross_fit:
        print(_cross_fit_summary(rows, args))
    confirmed = [r for r in failed if "confirm" in r]
    if confirmed:
        still = [r for r in confirmed if r["confirm"]["behind"]]
        print(f"re-measured on {args.confirm} fresh episodes: {len(still)} of the {len(confirmed)} still behind")
    if args.json is not None:
        args.json.write_text(jsonio.dumps({"task": args.task, "policy": policy.name, "design_seed": args.design_seed,
                                         "reach_below": args.reach_below,
                                         "seed": args.seed, "episodes": args.episodes, "rows": rows}, indent=1))
    return 0 if verdict == "met" else 1


if __name__ == "__main__":
    raise SystemExit(main())
