"""What predicts which goto setting a body prefers: l/r, or what ``plan`` sees in an episode?

The navigation policies follow ``plan`` under one of three settings, chosen by one feature
of the design, the reach l/r (:mod:`tumblebot.training.choice`). This script asks whether
another feature would choose better. It reads choice sweeps (each design's paired
difference of a later setting against ``plan`` on 48 episodes, with its standard error),
drives each swept design with ``plan`` for ``--episodes`` episodes and records what the
controller observes there: the mean yaw change of a spin step, its spread within an
episode, the mean length of a drive step and the number of spins. Then for each setting it
fits the difference by least squares on each set of features and prints the share of its
variance explained, in-sample and leave-one-out, beside the share that is not measurement
noise (1 − mean squared standard error / variance): the most any feature could explain.
Last, what a choice would gain: the setting taken on one side of a threshold on one
feature, fitted without the design it decides.

    .venv/bin/python reports/policy-headroom/setting_features.py \\
        training/checkpoints/plan-choice/sweep.jsonl training/checkpoints/tri-choice/short-sweep.jsonl
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing
import sys
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.control.goto import (
    FORWARD,
    NAVIGATORS,
    REVERSE,
    SPIN_NEGATIVE,
    SPIN_POSITIVE,
    GotoController,
    heading,
    wrap_angle,
)
from tumblebot.sim.observation import POSITION, QUATERNION
from tumblebot.sim.world.design import Design
from tumblebot.training.choice import comparisons, read_sweep
from tumblebot.training.config import TrainingError

FEATURES = ("reach", "spin", "spin_spread", "drive", "spins")
#: the feature sets fitted, each a least-squares line in its features
MODELS: tuple[tuple[str, ...], ...] = (("reach",), ("drive",), ("spin_spread",), ("spin",), ("reach", "drive"),
                                       ("reach", "spin_spread"), ("drive", "spin_spread"),
                                       ("reach", "spin", "spin_spread", "drive", "spins"))
_ENV: dict[str, Any] = {}


def _episode(job: tuple[str, tuple[float, ...], int, int]) -> tuple[float, float, float, int]:
    """One episode of ``plan``: mean and spread of a spin step's yaw change (rad), mean drive
    step length (m), number of spins. NaN where the episode had none of a kind."""
    from tumblebot.sim.evaluation.evaluate import episode_seed
    from tumblebot.sim.world.physics import THESIS

    task, design, seed, index = job
    if task not in _ENV:  # one environment per worker and task
        _ENV[task] = THESIS.make_env(task)
    env = _ENV[task]
    obs, _ = env.reset(seed=episode_seed(seed, index),
                       options={"design": Design.from_sequence(design, allow_out_of_bounds=True)})
    plan = GotoController(NAVIGATORS["plan"])
    spins: list[float] = []
    drives: list[float] = []
    for step in range(env.episode_steps):
        before, psi = np.asarray(obs[POSITION][:2], dtype=float), heading(np.asarray(obs[QUATERNION]))
        action = plan.act(obs, step)
        obs, _, terminated, truncated, _ = env.step(np.array(action))
        if action in (SPIN_POSITIVE, SPIN_NEGATIVE):
            spins.append(abs(wrap_angle(heading(np.asarray(obs[QUATERNION])) - psi)))
        elif action in (FORWARD, REVERSE):
            drives.append(float(np.hypot(*(np.asarray(obs[POSITION][:2]) - before))))
        if terminated or truncated:
            break
    nan = float("nan")
    return (float(np.mean(spins)) if spins else nan, float(np.std(spins)) if len(spins) > 1 else nan,
            float(np.mean(drives)) if drives else nan, len(spins))


def _differences(paths: list[Path]) -> dict[tuple[float, ...], dict[int, tuple[float, float]]]:
    """Each swept design's paired difference and standard error, by the setting compared."""
    out: dict[tuple[float, ...], dict[int, tuple[float, float]]] = {}
    for path in paths:
        for record in read_sweep(path):
            out.setdefault(tuple(record["design"]), {}).update(comparisons(record))
    return out


def _explained(y: np.ndarray, X: np.ndarray) -> tuple[float, float]:
    """Share of ``y``'s variance a least-squares line in ``X``'s columns explains: in-sample
    and leave-one-out."""
    A = np.column_stack([np.ones(len(y)), X])
    fitted = A @ np.linalg.lstsq(A, y, rcond=None)[0]
    held_out = np.empty(len(y))
    for i in range(len(y)):
        keep = np.arange(len(y)) != i
        held_out[i] = A[i] @ np.linalg.lstsq(A[keep], y[keep], rcond=None)[0]
    total = float(((y - y.mean()) ** 2).sum())
    return 1 - float(((y - fitted) ** 2).sum()) / total, 1 - float(((y - held_out) ** 2).sum()) / total


def _rule_gain(y: np.ndarray, x: np.ndarray) -> float:
    """Mean gain per design of taking the setting on one side of a threshold on ``x``, the
    side and threshold fitted (most summed gain) without the design it is applied to."""
    gained = 0.0
    for i in range(len(y)):
        keep = np.arange(len(y)) != i
        values = np.unique(x[keep])
        cuts = (values[1:] + values[:-1]) / 2  # between neighbouring designs
        best = max(((float(y[keep][side * x[keep] > side * t].sum()), side, t)
                    for t in cuts for side in (1, -1)), key=lambda c: c[0])
        gained += float(y[i]) if best[1] * x[i] > best[1] * best[2] else 0.0
    return gained / len(y)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sweeps", nargs="+", type=Path, help="choice sweep files (.jsonl)")
    parser.add_argument("--task", default="nav-flat", choices=("nav-flat", "nav-terrain"))
    parser.add_argument("--episodes", type=int, default=8, help="episodes of plan per design (8)")
    parser.add_argument("--seed", type=int, default=3, help="episode seed (3, the sweeps')")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", type=Path, help="also write each design's features and differences here")
    args = parser.parse_args(argv)
    if args.episodes < 2 or args.workers < 1:
        print("setting_features: need --episodes ≥ 2 and --workers ≥ 1", file=sys.stderr)
        return 2
    try:
        swept = _differences(args.sweeps)
    except (OSError, TrainingError) as exc:
        print(f"setting_features: {exc}", file=sys.stderr)
        return 2
    designs = list(swept)
    jobs = [(args.task, d, args.seed, i) for d in designs for i in range(args.episodes)]
    with contextlib.ExitStack() as stack:
        pool = (stack.enter_context(multiprocessing.get_context("forkserver").Pool(args.workers))
                if args.workers > 1 else None)
        seen = np.array(pool.map(_episode, jobs, chunksize=args.episodes) if pool is not None
                        else [_episode(j) for j in jobs], dtype=float).reshape(len(designs), args.episodes, 4)
    rows: list[dict[str, Any]] = [{"design": list(d), "reach": Design.from_sequence(d, allow_out_of_bounds=True).reach,
             "spin": float(np.nanmean(s[:, 0])), "spin_spread": float(np.nanmean(s[:, 1])),
             "drive": float(np.nanmean(s[:, 2])), "spins": float(s[:, 3].mean()),
             "differences": {str(k): v[0] for k, v in swept[d].items()},
             "errors": {str(k): v[1] for k, v in swept[d].items()}} for d, s in zip(designs, seen, strict=True)]
    print(f"{args.task}: {len(designs)} swept designs, {args.episodes} episodes of plan each (seed {args.seed})")
    for setting in sorted({int(k) for r in rows for k in r["differences"]}):
        usable = [r for r in rows if str(setting) in r["differences"]
                  and all(np.isfinite(r[f]) for f in FEATURES)]
        y = np.array([r["differences"][str(setting)] for r in usable])
        noise = float(np.mean([r["errors"][str(setting)] ** 2 for r in usable]))
        print(f"\nsetting {setting} − plan: {len(usable)} designs, mean {y.mean():+.4f}, sd {y.std():.4f}; "
              f"share not measurement noise {1 - noise / float(y.var()):.2f}")
        print(f"  {'features':42s} {'R²':>5s} {'leave-one-out':>13s}")
        for model in MODELS:
            X = np.column_stack([[r[f] for r in usable] for f in model])
            r2, loo = _explained(y, X)
            print(f"  {', '.join(model):42s} {r2:5.2f} {loo:13.2f}")
        print("  a threshold on one feature, fitted without the design it decides: mean gain per design "
              + ", ".join(f"{f} {_rule_gain(y, np.array([r[f] for r in usable])):+.4f}" for f in FEATURES))
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
