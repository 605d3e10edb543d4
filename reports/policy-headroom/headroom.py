"""How much better than a fixed gait can any controller do? A clairvoyant upper estimate.

For each evaluation episode (the same episodes ``tumblebot evaluate`` runs: same seeds,
same randomisation), the planner drives the robot step by step. At each step it tries all
nine actions from a snapshot of the simulation, each followed by the base gait to the end
of the episode, and keeps the action whose episode ends best. The snapshot includes the
motor noise and latency draws still to come, so the planner knows the future no policy
can know: this is one step of policy improvement over the base gait, with perfect
foresight. If it gains little, a learned policy cannot gain much more by deviating from
the gait now and then.

Run (about 15 s per incline episode on one core, 9 × 20 × 10 simulated steps):

    .venv/bin/python reports/policy-headroom/headroom.py --task incline \\
        --design 0.292,0.129,0.098,0.136 --episodes 48 --workers 2 --out results/incline-xi3.json
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import time
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.control.gaits import get_gait
from tumblebot.sim.evaluation.evaluate import episode_seed
from tumblebot.sim.evaluation.rollout import Actor, branch, drive, make_actor
from tumblebot.sim.evaluation.stats import mean_ci95
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.env import TumblerEnv
from tumblebot.sim.world.physics import THESIS

ACTIONS = [(right, left) for right in range(3) for left in range(3)]
_env: dict[str, Any] = {}


def _init(task: str, design: Design, base: str) -> None:
    _env["env"] = THESIS.make_env(task, design=design)
    _env["base"], _env["task"] = base, task


def _base(seed: int) -> Actor:
    """The base gait, its random draws (if any) started afresh from the episode's seed."""
    actor = make_actor("gait", _env["base"], _env["task"])
    actor.reset(seed, _env["env"].design.as_tuple())
    return actor


def _episode(job: tuple[int, int]) -> tuple[int, float, float, list[tuple[int, tuple[int, int]]]]:
    index, seed = job
    env: TumblerEnv = _env["env"]
    obs, _ = env.reset(seed=seed)
    start = env.snapshot()
    base_R = float(drive(env, _base(seed), obs)["final_R"])
    env.restore(start)
    env.release(start)
    deviations: list[tuple[int, tuple[int, int]]] = []
    info: dict[str, Any] = {}
    for step in range(env.episode_steps):
        here = env.snapshot()
        best: tuple[float, tuple[int, int]] | None = None
        for action in ACTIONS:
            value = float(branch(env, here, action, _base(seed), step)["final_R"])
            if best is None or value > best[0]:
                best = (value, action)
        assert best is not None
        env.restore(here)
        env.release(here)
        base_action = get_gait(_env["base"])(step, np.random.default_rng(seed))
        if best[1] != tuple(base_action):
            deviations.append((step, best[1]))
        _, _, _, _, info = env.step(np.array(best[1]))
    return index, base_R, float(info["final_R"]), deviations


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", required=True)
    parser.add_argument("--design", required=True, help="x,y,z,l in metres")
    parser.add_argument("--base", default="forward", help="the fixed gait to improve on (default forward)")
    parser.add_argument("--episodes", type=int, default=48)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", type=Path, default=None, help="write the results as JSON")
    args = parser.parse_args()
    design = Design.from_sequence([float(v) for v in args.design.split(",")])
    if args.base == "random":
        parser.error("--base must be a fixed gait")
    get_gait(args.base)
    jobs = [(i, episode_seed(args.seed, i)) for i in range(args.episodes)]
    t0 = time.perf_counter()
    with mp.get_context("forkserver").Pool(args.workers, _init, (args.task, design, args.base)) as pool:
        rows = []
        for row in pool.imap_unordered(_episode, jobs):
            rows.append(row)
            print(f"episode {row[0]:3d} ({len(rows)}/{args.episodes}): {args.base} {row[1]:+.3f}, "
                  f"planner {row[2]:+.3f}, deviations {row[3]}", flush=True)
    rows.sort()
    base = np.array([r[1] for r in rows])
    planned = np.array([r[2] for r in rows])
    gain = planned - base
    result = {
        "task": args.task, "design": list(design.as_tuple()), "base_gait": args.base, "seed": args.seed,
        "episodes": args.episodes, "wall_seconds": round(time.perf_counter() - t0, 1),
        "base_mean_R": float(base.mean()), "base_sd_R": float(base.std(ddof=1)),
        "planner_mean_R": float(planned.mean()), "planner_sd_R": float(planned.std(ddof=1)),
        "gain_mean": float(gain.mean()), "gain_ci95": list(mean_ci95(gain)),
        "deviations_per_episode": float(np.mean([len(r[3]) for r in rows])),
        # The gain a controller needs over the gait for Welch's one-sided p < 0.01 with 240
        # episodes each, at this spread: z(0.99) · sd · sqrt(2 / 240).
        "gain_needed_for_the_card_bar": float(2.326 * base.std(ddof=1) * np.sqrt(2 / 240)),
        "per_episode": [{"episode": r[0], "base_R": r[1], "planner_R": r[2],
                         "deviations": [[step, list(a)] for step, a in r[3]]} for r in rows],
    }
    print(f"{args.task} on {design}: {args.base} {result['base_mean_R']:.3f}, clairvoyant one-step planner "
          f"{result['planner_mean_R']:.3f} (gain {result['gain_mean']:+.3f}, 95 % CI "
          f"{result['gain_ci95'][0]:+.3f} to {result['gain_ci95'][1]:+.3f}; the card's bar needs about "
          f"{result['gain_needed_for_the_card_bar']:+.3f})")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
