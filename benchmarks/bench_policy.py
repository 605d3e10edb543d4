"""Policy inference latency and evaluation throughput.

Run: ``.venv/bin/python benchmarks/bench_policy.py --run RUN --policy POLICY.onnx``
(defaults: the committed run the bundled ``nav-flat`` policy was exported from,
``training/checkpoints/plan-nav-flat``, and that policy).

1. Latency per observation, onnxruntime (:class:`OnnxPolicy`, what evaluation, the
   optimiser and the host use) against SB3 ``predict(deterministic=True)``, median and p99:
   the graph alone (``act_batch`` on a ready input), and ``act`` (for a ``context``
   policy that includes building the input from the thesis observation).
2. Evaluation throughput on nav-flat: whole episodes with the policy in the loop, against
   the same episodes without it (reset with the same seed, the policy's actions replayed:
   the same physics), and against bare stepping of the same scenes with both legs driving
   forward (same substeps, the DC motor update each substep), interleaved in one run. The
   first ratio is the policy's overhead; the second also counts what the policy's own
   motion (stops held against the servos' holding torque, spins) costs the physics engine
   over forward driving.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from tumblebot.sim.control.policy import OnnxPolicy, bundled_policy
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.env import TumblerEnv
from tumblebot.sim.world.randomization import Randomization

from bench_env import time_raw_episode  # same folder


def latency(run: Path, policy: OnnxPolicy, n: int) -> None:
    from stable_baselines3 import PPO

    model = PPO.load(run / "latest.zip" if run.is_dir() else run, device="cpu")
    size = int(model.observation_space.shape[0])  # type: ignore[index]
    if size != policy.context.size:
        raise SystemExit(f"--run takes {size} inputs, the policy {policy.context.size}: give the run it came from")
    rng = np.random.default_rng(0)
    inputs = rng.normal(size=(n, size)).astype(np.float32)
    graph_t, act_t, sb3_t = [], [], []
    policy.reset((0.292, 0.129, 0.098, 0.136))
    for k, x in enumerate(inputs):
        if k % 20 == 0:
            policy.reset((0.292, 0.129, 0.098, 0.136))
        t0 = time.perf_counter()
        policy.act_batch(x[None])
        t1 = time.perf_counter()
        policy.act(x[:9])
        t2 = time.perf_counter()
        model.predict(x, deterministic=True)
        t3 = time.perf_counter()
        graph_t.append(t1 - t0)
        act_t.append(t2 - t1)
        sb3_t.append(t3 - t2)
    print(f"inference latency per observation ({n} calls, interleaved; {policy.layout} input, {size} numbers)")
    for name, ts in (("onnx graph", graph_t), ("OnnxPolicy.act", act_t), ("SB3 predict", sb3_t)):
        print(f"  {name:<15} median {np.median(ts) * 1e6:7.1f} µs   p99 {np.percentile(ts, 99) * 1e6:7.1f} µs")
    print(f"  SB3/onnx-graph median ratio {np.median(sb3_t) / np.median(graph_t):.1f}×")


def throughput(policy: OnnxPolicy, episodes: int) -> None:
    env = TumblerEnv(task="nav-flat", design=Design(0.292, 0.129, 0.098, 0.136),
                     randomization=Randomization(design=False))
    t_eval, t_same, t_raw, t_reset, t_infer = [], [], [], [], []
    for i in range(episodes):
        start = time.perf_counter()
        obs, _ = env.reset(seed=i)
        policy.reset(env.design.as_tuple())
        t_reset.append(time.perf_counter() - start)
        infer, actions = 0.0, []
        for _ in range(env.episode_steps):
            t0 = time.perf_counter()
            action = policy.act(obs)
            infer += time.perf_counter() - t0
            actions.append(action)
            obs, *_ = env.step(action)
        t_eval.append(time.perf_counter() - start)
        t_infer.append(infer)
        start = time.perf_counter()  # the same episode (seed, actions, physics) without the policy
        env.reset(seed=i)
        for action in actions:
            env.step(action)
        t_same.append(time.perf_counter() - start)
        t_raw.append(time_raw_episode(env, i, motor_update=True))
    env.close()
    e, same, r = statistics.median(t_eval), statistics.median(t_same), statistics.median(t_raw)
    # Ratios episode by episode (each pair timed back to back), then their median: the
    # machine's drift over the run cancels, which medians of the three columns do not.
    over_same = statistics.median(a / b for a, b in zip(t_eval, t_same, strict=True)) - 1
    over_raw = statistics.median(a / b for a, b in zip(t_eval, t_raw, strict=True)) - 1
    same_raw = statistics.median(a / b for a, b in zip(t_same, t_raw, strict=True)) - 1
    print(f"\nnav-flat evaluation, medians of {episodes} episodes (interleaved)")
    print(f"  policy episodes   {e * 1e3:7.1f} ms  ({1 / e:.2f} episodes/s per core)")
    print(f"  the same episodes {same * 1e3:7.1f} ms  (reset, then the policy's actions replayed: the same physics)")
    print(f"  bare stepping     {r * 1e3:7.1f} ms  (the same scenes and settling, both legs driving forward, "
          "motors set each substep)")
    print(f"  overhead of the policy       {100 * over_same:+.1f} %  (policy episodes / the same episodes, "
          "median of the per-episode ratios)")
    print(f"  over bare forward stepping   {100 * over_raw:+.1f} %  (also counts the physics of the policy's "
          f"own motion: the same episodes are {100 * same_raw:+.1f} %)")
    print(f"  of which: reset (scene rebuild + settling) {statistics.median(t_reset) * 1e3:.1f} ms, "
          f"inference (input, features, graph) {statistics.median(t_infer) * 1e3:.2f} ms per episode")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, default=Path("training/checkpoints/plan-nav-flat"),
                        help="SB3 run folder or .zip (default: the committed run of the bundled nav-flat policy)")
    parser.add_argument("--policy", type=Path, default=None, help="ONNX policy (default: bundled nav-flat)")
    parser.add_argument("--calls", type=int, default=5000)
    parser.add_argument("--episodes", type=int, default=20)
    args = parser.parse_args()
    policy = OnnxPolicy(args.policy or bundled_policy("nav-flat"))
    print(f"tumblebot policy benchmark, {time.strftime('%Y-%m-%d')}, {platform.machine()}, "
          f"Python {platform.python_version()}, policy {policy.path.name}")
    latency(args.run, policy, args.calls)
    throughput(policy, args.episodes)


if __name__ == "__main__":
    main()
