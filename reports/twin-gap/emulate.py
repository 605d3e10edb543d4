"""The digital twin's actuation, emulated in one process: does it explain the twin's gap?

The twin (``tumblebot twin run``) steps the world with :meth:`TumblerEnv.advance`, which
redraws the motors' speed noise every simulated second from the robot's placement, and
switches the legs when the firmware's pulses change; ``tumblebot evaluate`` steps with
:meth:`TumblerEnv.step`, which draws a new speed with every command and delays it by 0–40
ms. This script drives a policy both ways from the same random starts on the 1.5 m circle
around the setpoint (the twin's), on the ξ = 3 robot:

* *emulated*: the world as the twin builds it (no added latency), the first decision at a
  random offset after placement (0–1 s, so noise redraws and decisions are out of phase as
  in the twin), each command applied 0–21 ms after the pose it was decided on (the link
  and the 20 ms servo frame) and held until the next;
* *step()*: what ``evaluate`` and the twin's ``--check`` run.

It leaves out the processes, the links and real time. Run from the repository root:
``.venv/bin/python reports/twin-gap/emulate.py [--policy FILE] [--episodes 300]``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from tumblebot.defaults import XI3_ROBOT
from tumblebot.sim.control.policy import bundled_policy
from tumblebot.sim.evaluation.rollout import Actor, make_actor, run_episode
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.env import TumblerEnv
from tumblebot.sim.world.randomization import Randomization

XI3 = Design(*XI3_ROBOT)


def emulated_episode(world: TumblerEnv, actor: Actor, seed: int, options: dict[str, object], offset: int,
                     latency: int, first_latency: int | None = None) -> float:
    """Final distance to the setpoint with the twin's actuation schedule (substeps)."""
    world.reset(seed=seed, options=options)
    actor.reset(seed, world.design.as_tuple())
    world.set_leg_commands(0.0, 0.0)
    world.advance(offset)
    for step in range(world.episode_steps):
        action = np.asarray(actor.act(world.observation(), step)).reshape(-1) - 1.0
        late = first_latency if step == 0 and first_latency is not None else latency
        world.advance(late)
        world.set_leg_commands(float(action[0]), float(action[1]))
        world.advance(world.substeps - late)
    position, _ = world.base_pose()
    return math.hypot(position[0], position[1])


def summary(name: str, errors: list[float]) -> str:
    e = np.asarray(errors)
    return (f"{name:<10} mean {e.mean():.3f} m  median {np.median(e):.3f} m  p90 {np.percentile(e, 90):.3f} m  "
            f"beyond 0.3 m {100 * np.mean(e > 0.3):4.1f} %")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", type=Path, default=None, help="ONNX policy (default: the bundled nav-flat)")
    parser.add_argument("--episodes", type=int, default=300)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--first-late", metavar="LO,HI", default=None,
                        help="the first decision lands LO-HI ms late (the twin before 2026-12-02: 100,250)")
    args = parser.parse_args()
    first_late: tuple[int, int] | None = None
    if args.first_late is not None:
        try:
            lo, hi = (round(float(v) * 240 / 1000) for v in args.first_late.split(","))
        except ValueError:
            parser.error("--first-late must be LO,HI in ms, e.g. 100,250")
        if not 0 <= lo <= hi < 240:
            parser.error("--first-late must be LO,HI with 0 <= LO <= HI < 1000 ms")
        first_late = (lo, hi)
    policy = args.policy or bundled_policy("nav-flat")
    actor = make_actor("onnx", str(policy), "nav-flat")
    world = TumblerEnv(task="nav-flat", design=XI3, randomization=Randomization(design=False, latency=(0.0, 0.0)))
    env = TumblerEnv(task="nav-flat", design=XI3, randomization=Randomization(design=False))
    rng = np.random.default_rng(args.seed)
    emulated: list[float] = []
    stepped: list[float] = []
    started = time.monotonic()
    try:
        for i in range(args.episodes):
            bearing, yaw = rng.uniform(0, 2 * math.pi), rng.uniform(-math.pi, math.pi)
            options: dict[str, object] = {"start_xy": (1.5 * math.cos(bearing), 1.5 * math.sin(bearing)),
                                          "start_yaw": yaw}
            seed = 10_000 * args.seed + i
            offset, latency = int(rng.integers(0, world.substeps)), int(rng.integers(0, 6))
            first = int(rng.integers(first_late[0], first_late[1] + 1)) if first_late else None
            emulated.append(emulated_episode(world, actor, seed, options, offset, latency, first))
            final = run_episode(env, actor, seed, options=options).final_position
            stepped.append(math.hypot(final[0], final[1]))
    finally:
        world.close()
        env.close()
    late = f", first decision {args.first_late} ms late" if first_late else ""
    print(f"{policy.name}, ξ = 3 robot, {args.episodes} starts on the 1.5 m circle (seed {args.seed}){late}, "
          f"{time.strftime('%Y-%m-%d')}, {time.monotonic() - started:.0f} s")
    print(summary("emulated", emulated))
    print(summary("step()", stepped))


if __name__ == "__main__":
    main()
