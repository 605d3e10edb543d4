"""goto's endgame: no spins in the last 3 steps against the default (last 2), side by side.

Run: ``.venv/bin/python benchmarks/bench_goto_endgame.py [--episodes 240] [--workers 2]``

On every design of the model card's grid (``training/card_eval.py`` ``NAV_GRID``), ``nav-flat``,
the same episodes for both settings (seed 0, common random numbers): mean final R of
``GotoConfig(spin_steps_left=2)`` (the default) and ``spin_steps_left=3``, their difference
and a paired t-test. A late spin moves the robot by an amount the observation does not
predict, so barring it near the end should help.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import platform
import signal
import time
from typing import Any

import numpy as np

from tumblebot.sim.control.goto import GotoConfig, GotoController
from tumblebot.sim.evaluation.evaluate import episode_seed
from tumblebot.sim.evaluation.rollout import run_episode
from tumblebot.sim.report import paired_p
from tumblebot.sim.world.design import Design
from tumblebot.training.card_eval import NAV_GRID

SETTINGS = (2, 3)
_ENV: dict[str, Any] = {}


class _Goto:
    def __init__(self, spin_steps_left: int) -> None:
        self.goto = GotoController(GotoConfig(spin_steps_left=spin_steps_left))

    def reset(self, seed: int, design: tuple[float, float, float, float]) -> None:
        self.goto.reset()

    def act(self, obs: np.ndarray, step: int) -> np.ndarray:
        return np.array(self.goto.act(obs, step))


def _init() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _episode(job: tuple[tuple[float, ...], int, int]) -> float:
    from tumblebot.sim.world.env import TumblerEnv
    from tumblebot.sim.world.randomization import Randomization

    w, spin_steps_left, seed = job
    if "env" not in _ENV:
        _ENV["env"] = TumblerEnv(task="nav-flat", randomization=Randomization(design=False))
    out = run_episode(_ENV["env"], _Goto(spin_steps_left), seed, options={"design": Design.from_sequence(w)})
    return out.final_R


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=240)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    seeds = [episode_seed(0, i) for i in range(args.episodes)]
    started = time.monotonic()
    print(f"goto endgame, nav-flat, {args.episodes} episodes per design and setting, seed 0 "
          f"({time.strftime('%Y-%m-%d')}, {platform.machine()}, {mp.cpu_count()} cores, {args.workers} workers)")
    print("| design | (x, y, z, l) | spin_steps_left=2 (default) | 3 | difference | p (paired) |")
    print("|---|---|---|---|---|---|")
    diffs = []
    with mp.get_context("forkserver").Pool(args.workers, initializer=_init) as pool:
        for label, design in NAV_GRID.items():
            R = {k: np.asarray(pool.map(_episode, [(design.as_tuple(), k, s) for s in seeds], chunksize=8))
                 for k in SETTINGS}
            diff = float(np.mean(R[3]) - np.mean(R[2]))
            diffs.append(diff)
            w = ", ".join(f"{v:.3f}" for v in design.as_tuple())
            print(f"| {label} | ({w}) | {np.mean(R[2]):.3f} | {np.mean(R[3]):.3f} | {diff:+.3f} | "
                  f"{paired_p(R[3], R[2]):.2g} |", flush=True)
    print(f"| mean | | | | {np.mean(diffs):+.3f} | |")
    print(f"never worse: {all(d >= -1e-12 for d in diffs)}; {time.monotonic() - started:.0f} s")


if __name__ == "__main__":
    main()
