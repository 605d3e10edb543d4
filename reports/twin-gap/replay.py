"""Replay a twin trial set in one process, from the world's log of leg changes.

The twin's world (``host/twin.py``) writes ``legs R L from substep N`` to
``twin-world.log`` whenever the servo pulses on the emulated pins change the legs'
commands, and ``placed: {...}`` at each trial's start. This script rebuilds each trial
from those lines alone (the same seed, start and servo; ``TumblerEnv.advance`` one
substep at a time), compares every pose the world published (``/pose`` in the trial's
MCAP log) with the replay's, and prints how late each of the host's decisions reached the
legs (the first leg change toward the decided command, after the decision).

A replay that matches to the bit says that the twin's physics is the simulator's, and
that the twin differs from ``tumblebot evaluate`` only in when the legs change. A set run
with ``--world-physics`` is replayed under that hidden profile (its latency is already in
the logged leg changes).

The world draws each trial's randomness (the legs' angles, masses, friction, motor noise)
from the set's seed, so a set run again repeats its draws. ``--other-seeds N`` replays
each trial's leg changes with the draws of N other seeds as well, and prints how far each
trial went from its first leg change to its end: the set's own draws against others at
the same timing, i.e. how lucky the set was.

Run from the repository root: ``.venv/bin/python reports/twin-gap/replay.py TRIAL_SET
[--other-seeds N]`` (a folder written by ``tumblebot twin run``).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.host.trial_sets import TrialPlan, load_index
from tumblebot.host.triallog import read_trial
from tumblebot.host.twin import twin_servo, twin_world_physics, world_env
from tumblebot.sim.evaluation.evaluate import episode_seed
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.env import TumblerEnv

Change = tuple[int, float, float]  # substep, right, left


def world_log(folder: Path) -> dict[int, tuple[dict[str, Any], list[Change]]]:
    """Each trial's placement and leg changes, from ``twin-world.log``."""
    trials: dict[int, tuple[dict[str, Any], list[Change]]] = {}
    current: int | None = None
    for line in (folder / "twin-world.log").read_text().splitlines():
        if line.startswith("placed: "):
            placed = json.loads(line[len("placed: "):])
            current = int(placed["trial"])
            trials[current] = (placed, [])
        elif line.startswith("legs ") and current is not None:
            parts = line.split()
            trials[current][1].append((int(parts[-1]), float(parts[1]), float(parts[2])))
    if not trials:
        raise SystemExit(f"{folder / 'twin-world.log'} has no leg changes (a set from before they were logged)")
    return trials


def decision_latencies(log: Any, changes: list[Change], hz: int) -> list[float]:
    """Milliseconds from each decision that changed the command to the legs changing."""
    poses = [(m.log_time, m.data["source_time"]) for m in log.topic("/pose")]
    arrival = np.array([t for t, _ in poses])
    source = np.array([s for _, s in poses])
    out, previous = [], (0, 0)
    for message in log.topic("/decision"):
        i = max(0, int(np.searchsorted(arrival, message.log_time, side="right")) - 1)
        at = (source[i] + message.log_time - arrival[i]) * hz  # the decision, in world substeps
        command = (int(message.data["command"][0]), int(message.data["command"][1]))
        reached = [s for s, r, lft in changes if s >= at - 1 and (round(r), round(lft)) == command]
        if command != previous and reached:
            out.append(1e3 * (reached[0] - at) / hz)
        previous = command
    return out


def run(world: TumblerEnv, seed: int, placed: dict[str, Any], changes: list[Change], end: int,
        published: dict[int, Any] | None = None) -> tuple[float, float]:
    """One trial rebuilt from its placement and leg changes with the draws of ``seed``, up to
    substep ``end``: (the most it strays from the ``published`` poses, in m; the distance
    from the first leg change to the end, in m)."""
    world.reset(seed=seed, options={"start_xy": (placed["x"], placed["y"]), "start_yaw": placed["yaw"]})
    world.set_leg_commands(0.0, 0.0)
    substep, worst = 0, 0.0
    first: tuple[float, float, float] | None = None
    for until, right, left in [*changes, (end, None, None)]:
        while substep < until:
            world.advance(1)
            substep += 1
            if published is not None and substep in published:
                worst = max(worst, math.dist(world.base_pose()[0], published[substep]))
        if first is None:
            first = world.base_pose()[0]
        if right is not None and left is not None:
            world.set_leg_commands(right, left)
    last = world.base_pose()[0]
    assert first is not None  # the loop ran at least once
    return worst, math.hypot(last[0] - first[0], last[1] - first[1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="a trial set written by tumblebot twin run")
    parser.add_argument("--other-seeds", type=int, default=0, metavar="N",
                        help="also replay each trial with the draws of N other sets' seeds (default 0)")
    args = parser.parse_args()
    if args.other_seeds < 0:
        parser.error("--other-seeds must be 0 or more")
    plan = TrialPlan.from_json(json.loads((args.folder / "plan.json").read_text()))
    index = {int(e["trial"]): e for e in load_index(args.folder)["trials"]}
    # the world the twin ran; a hidden world's latency only delays commands given to step(),
    # and is already in the logged leg changes
    world = world_env(Design(*plan.design), twin_servo(args.folder), twin_world_physics(args.folder))
    own, others = [], []
    try:
        for trial, (placed, changes) in sorted(world_log(args.folder).items()):
            if trial not in index:
                continue  # an aborted attempt: the finished one is placed again later
            log = read_trial(args.folder / index[trial]["file"])
            published = {round(m.data["source_time"] * world.physics_hz): m.data["p"] for m in log.topic("/pose")}
            end = max(published)
            worst, went = run(world, episode_seed(plan.seed, trial), placed, changes, end, published)
            late = decision_latencies(log, changes, world.physics_hz)
            line = (f"trial {trial}: {len(published)} poses, replay off by at most {worst:.6f} m; "
                    f"decisions reached the legs after {', '.join(f'{ms:.0f}' for ms in late)} ms")
            if args.other_seeds:
                drawn = [run(world, episode_seed(plan.seed + 1 + k, trial), placed, changes, end)[1]
                         for k in range(args.other_seeds)]
                own.append(went)
                others.append(float(np.mean(drawn)))
                line += f"; went {went:.3f} m, with other draws {others[-1]:.3f} m"
            print(line, flush=True)
    finally:
        world.close()
    if own:
        print(f"mean distance from the first leg change to the end: {np.mean(own):.3f} m with the set's own draws, "
              f"{np.mean(others):.3f} m with {args.other_seeds} other seeds' (seeds {plan.seed + 1}.."
              f"{plan.seed + args.other_seeds}), over {len(own)} trials")


if __name__ == "__main__":
    main()
