"""Training throughput against the bare environments, on this machine's cores.

Run: ``.venv/bin/python benchmarks/bench_train.py [--steps N] [--envs K] [--rounds R] [--observation L]``

Interleaved in one run, ``R`` rounds of each (machines are shared and noisy, so only the
ratios measured side by side mean anything), all on the same ``SubprocVecEnv`` of ``K``
``nav-flat`` environments with the bundled policy's ``dual`` observation (or ``--observation``),
over designs that can tumble:

* ``bare``: ``N`` vectorised steps with random actions (the physics and the pipes alone);
* ``DAgger``: ``N`` steps of :func:`tumblebot.training.imitation.collect` with the
  student driving (its inference and goto's labels in the loop);
* ``PPO``: ``N`` steps of ``PPO.learn`` with the bundled fine-tune's settings (rollout
  plus the gradient updates).

The ratio to ``bare`` is each method's training overhead.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tumblebot.training.config import TrainConfig
from tumblebot.training.imitation import collect
from tumblebot.training.ppo import StopRequest, build_vec_env, new_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=4096, help="environment steps per measurement")
    parser.add_argument("--envs", type=int, default=4, help="environments (the bundled runs used 4 on 2 cores)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--observation", choices=("context", "memory", "residual", "dual"), default="dual",
                        help="policy input (default dual, the bundled navigation policies')")
    args = parser.parse_args()
    config = TrainConfig(task="nav-flat", observation=args.observation, tumbling_designs_only=True, n_envs=args.envs,
                         net_arch=[256, 256], n_steps=max(args.steps // args.envs, 1), batch_size=512, n_epochs=5,
                         learning_rate=5e-5, clip_range=0.1, ent_coef=0.0)
    print(f"tumblebot training benchmark, {time.strftime('%Y-%m-%d')}, {platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}; {args.envs} environments, "
          f"{args.steps} steps per measurement, {args.rounds} rounds, {args.observation} observation")
    env = build_vec_env(config, seed=0)
    times: dict[str, list[float]] = {"bare": [], "DAgger": [], "PPO": []}
    with tempfile.TemporaryDirectory() as tmp:
        model = new_model(config, env, Path(tmp))
        rng = np.random.default_rng(0)
        for _ in range(args.rounds):
            env.reset()
            start = time.perf_counter()
            for _ in range(args.steps // args.envs):
                env.step(rng.integers(0, 3, (args.envs, 2)))
            times["bare"].append(time.perf_counter() - start)

            start = time.perf_counter()
            with tqdm(disable=True) as bar:
                collect(model, env, args.steps // 20, True, 0.98, 20, StopRequest(), bar)
            times["DAgger"].append(time.perf_counter() - start)

            start = time.perf_counter()
            model.learn(total_timesteps=config.n_steps * args.envs, reset_num_timesteps=False)
            times["PPO"].append(time.perf_counter() - start)
    env.close()
    bare = statistics.median(times["bare"])
    print(f"{'':8} {'median s':>9} {'steps/s':>9} {'vs bare':>8}")
    for name, ts in times.items():
        t = statistics.median(ts)
        print(f"{name:8} {t:9.2f} {args.steps / t:9.0f} {t / bare:7.2f}×")


if __name__ == "__main__":
    main()
