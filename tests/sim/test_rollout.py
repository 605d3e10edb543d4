"""tumblebot.sim.evaluation.rollout: the one episode loop, and branching from a snapshot."""

from __future__ import annotations

import copy
from functools import partial

import numpy as np

from tumblebot.sim.control.goto import NAVIGATORS, GotoController
from tumblebot.sim.evaluation.rollout import GotoActor, branch, drive
from tumblebot.sim.world.design import THESIS_ROBOTS
from tumblebot.sim.world.env import TumblerEnv


def test_that_a_branch_with_the_actors_own_action_replays_the_episode_and_another_action_changes_it() -> None:
    env = TumblerEnv(task="nav-flat", design=THESIS_ROBOTS["3"])
    try:
        for seed, at in ((0, 0), (1, 7), (2, 19)):  # the first step, one mid-episode, the last
            obs, _ = env.reset(seed=seed)
            goto = GotoController(NAVIGATORS["plan"])
            for step in range(at):
                obs, *_ = env.step(np.array(goto.act(obs, step)))
            snap = env.snapshot()

            def told(action: tuple[int, int], before: GotoController = goto, obs: np.ndarray = obs,
                     at: int = at) -> GotoActor:
                """goto's memory before the step, having seen ``action`` taken."""
                follower = copy.deepcopy(before)
                follower.act(obs, at)
                follower.taken(action)
                return GotoActor(follower)

            action = copy.deepcopy(goto).act(obs, at)
            episode = drive(env, GotoActor(copy.deepcopy(goto)), obs, at)
            replayed = branch(env, snap, action, told(action), at)
            assert replayed["final_R"] == episode["final_R"]  # the same noise to come and actions: the same end
            other = (0, 0) if action != (0, 0) else (2, 2)
            assert branch(env, snap, other, told(other), at)["final_position"] != episode["final_position"]
            if at < 19:  # before_step runs after the restore: a future drawn anew is not the episode's own
                drawn = branch(env, snap, action, told(action), at, partial(env.reseed_motor_noise, [99, at]))
                assert drawn["final_position"] != episode["final_position"]
            env.release(snap)
    finally:
        env.close()
