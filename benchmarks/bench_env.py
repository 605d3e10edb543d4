"""Environment overhead against raw PyBullet stepping, and the two motor models.

Run: ``.venv/bin/python benchmarks/bench_env.py [--episodes N]``

For each task it times, interleaved in one run (the machines are shared and noisy, so
only ratios measured side by side mean anything):

* ``env``: whole episodes through :class:`TumblerEnv` (reset + 20 steps, both legs
  forward, full domain randomisation, DC motor model);
* ``raw+motor``: the same scene and the same number of substeps, driven by a bare loop
  of ``stepSimulation`` plus the DC motor update the physics needs each substep;
* ``raw``: the same scene and substeps with ``stepSimulation`` alone (motors set once).

It then compares the DC torque–speed motor model with the velocity-with-force-cap
approximation on the distance task (distance covered by a fixed gait, time per episode).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from typing import Any

import numpy as np
import psutil

from tumblebot.sim.world.env import MotorModel, TumblerEnv
from tumblebot.sim.world.randomization import Randomization
from tumblebot.sim.world.tasks import TASKS

FORWARD = np.array([2, 2])


def time_env_episode(env: TumblerEnv, seed: int) -> float:
    start = time.perf_counter()
    env.reset(seed=seed)
    for _ in range(env.episode_steps):
        env.step(FORWARD)
    return time.perf_counter() - start


def time_raw_episode(env: TumblerEnv, seed: int, motor_update: bool) -> float:
    """Rebuild the same scene (through reset, not timed), then step it bare."""
    env.reset(seed=seed)
    env._command = np.ones(2)
    env._set_motors(env._command)
    p, client = env._p, env._client
    substeps = env.episode_steps * env.substeps
    start = time.perf_counter()
    if motor_update:
        set_motors = env._set_motors
        command = env._command
        for _ in range(substeps + env.settle_substeps):
            set_motors(command)
            p.stepSimulation(physicsClientId=client)
    else:
        for _ in range(substeps + env.settle_substeps):
            p.stepSimulation(physicsClientId=client)
    return time.perf_counter() - start


def time_reset(env: TumblerEnv, seed: int) -> float:
    start = time.perf_counter()
    env.reset(seed=seed)
    return time.perf_counter() - start


def overhead(episodes: int) -> None:
    print(f"{'task':<14} {'env ms':>8} {'raw+motor':>10} {'raw ms':>8} {'reset ms':>9} "
          f"{'env/(raw+motor)':>16} {'env/raw':>8} {'RSS Δ MB':>9}")
    for name in TASKS:
        env = TumblerEnv(task=name)
        rss0 = psutil.Process().memory_info().rss
        t_env, t_raw_m, t_raw, t_reset = [], [], [], []
        for i in range(episodes):
            t_env.append(time_env_episode(env, i))
            t_raw_m.append(time_raw_episode(env, i, motor_update=True))
            t_raw.append(time_raw_episode(env, i, motor_update=False))
            t_reset.append(time_reset(env, i))
        rss = (psutil.Process().memory_info().rss - rss0) / 2**20
        env.close()
        med = {k: statistics.median(v) * 1e3 for k, v in
               (("env", t_env), ("rawm", t_raw_m), ("raw", t_raw), ("reset", t_reset))}
        # env includes its reset (scene build, settling); the raw loops run the same
        # substeps (settling included) on the same scene and charge no build.
        ratio = med["env"] / med["rawm"]
        print(f"{name:<14} {med['env']:>8.1f} {med['rawm']:>10.1f} {med['raw']:>8.1f} {med['reset']:>9.1f} "
              f"{ratio:>16.3f} {med['env'] / med['raw']:>8.3f} {rss:>9.1f}")


def motor_models(episodes: int) -> None:
    print("\nMotor models on distance-flat, gait 'forward', nominal robot (ξ = 3), no randomisation "
          "but the start pose")
    rnd = Randomization(design=False, mass_rel_sigma=0, inertia_rel_sigma=0, friction_rel_sigma=0,
                        motor_speed_sigma=0, latency=(0.0, 0.0))
    results: dict[str, tuple[list[float], list[float]]] = {}
    models: tuple[MotorModel, ...] = ("dc", "velocity")
    envs = {m: TumblerEnv(task="distance-flat", randomization=rnd, motor_model=m) for m in models}
    for m in envs:
        results[m] = ([], [])
    for i in range(episodes):
        for m, env in envs.items():
            start = time.perf_counter()
            env.reset(seed=i)
            info: dict[str, Any] = {}
            for _ in range(env.episode_steps):
                _, _, _, _, info = env.step(FORWARD)
            results[m][1].append(time.perf_counter() - start)
            results[m][0].append(float(info["final_position"][0]))
    for env in envs.values():
        env.close()
    print(f"{'model':<10} {'mean px m':>10} {'sd':>6} {'episode ms':>11}")
    for model, (dist, wall) in results.items():
        print(f"{model:<10} {statistics.mean(dist):>10.3f} {statistics.stdev(dist):>6.3f} "
              f"{statistics.median(wall) * 1e3:>11.1f}")
    d_dc, d_v = statistics.mean(results["dc"][0]), statistics.mean(results["velocity"][0])
    t_dc, t_v = statistics.median(results["dc"][1]), statistics.median(results["velocity"][1])
    print(f"velocity/dc: distance {d_v / d_dc:.3f}, time per episode {t_v / t_dc:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=10, help="episodes per task and variant")
    args = parser.parse_args()
    print(f"tumblebot env benchmark, {time.strftime('%Y-%m-%d')}, {platform.processor() or platform.machine()}, "
          f"{psutil.cpu_count()} CPUs, Python {platform.python_version()}; medians of {args.episodes} episodes")
    overhead(args.episodes)
    motor_models(max(args.episodes, 8))


if __name__ == "__main__":
    main()
