"""How much a navigation policy could gain over ``goto`` step by step, from the search's scores.

``tumblebot imitate --refine RUN --draws K`` scores every one of the nine actions in the
searched steps by the mean final R over K futures drawn anew, each action followed by
``goto`` to the end, and keeps the scores in ``RUN/dagger.npz`` (``values``; NaN where the
step was not searched). This prints, for each searched step of the episode, how often
goto took each action, every action's mean advantage over goto's own action, and the mean
of the per-state best advantage. The last is what a teacher that sees the hidden state
(leg angles, masses, friction) gains, before the bias of taking the maximum of noisy
estimates; a policy, which sees only its observation, gains at most what the best action
*on average over states that look alike to it* gains.

    .venv/bin/python reports/policy-headroom/goto_advantage.py [training/checkpoints/res-nav-flat/search-values.npz]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from tumblebot.sim.control.policy import EPISODE_STEPS, LAYOUTS
from tumblebot.training.lookahead import ALL_ACTIONS

DEFAULT = Path("training/checkpoints/res-nav-flat/search-values.npz")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path, nargs="?", default=DEFAULT,
                        help=f"a refine run's dagger.npz, or the searched states of one (default {DEFAULT})")
    args = parser.parse_args(argv)
    if not args.data.is_file():
        print(f"goto_advantage: {args.data} does not exist", file=sys.stderr)
        return 2
    data = np.load(args.data)
    if "values" not in data or "goto_labels" not in data:
        print(f"goto_advantage: {args.data} has no search scores (values, goto_labels): "
              "make it with tumblebot imitate --refine … --draws K", file=sys.stderr)
        return 2
    searched = np.isfinite(data["values"][:, 0])
    values, own = data["values"][searched], data["goto_labels"][searched]
    steps_left = data["inputs"][searched, LAYOUTS["context"].index("steps_left")]
    step = np.rint(EPISODE_STEPS * (1.0 - steps_left)).astype(int)
    index = np.array([ALL_ACTIONS.index((int(a[0]), int(a[1]))) for a in own])
    advantage = values - values[np.arange(len(values)), index][:, None]
    print(f"{len(values)} searched states from {args.data}")
    print("step  states  goto's actions (count)             best fixed alternative (mean advantage)  "
          "per-state best (mean)")
    for k in sorted(set(step.tolist())):
        rows = step == k
        counts = np.bincount(index[rows], minlength=len(ALL_ACTIONS))
        taken = ", ".join(f"{ALL_ACTIONS[i]}: {c}" for i, c in enumerate(counts) if c)
        mean = advantage[rows].mean(axis=0)
        others = [i for i in range(len(ALL_ACTIONS)) if counts[i] < rows.sum()]
        alt = max(others, key=lambda i: mean[i]) if others else int(np.argmax(mean))
        print(f"{k:4d}  {int(rows.sum()):6d}  {taken:36s}  {ALL_ACTIONS[alt]} ({mean[alt]:+.3f})"
              f"{'':21s}{advantage[rows].max(axis=1).mean():+.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
