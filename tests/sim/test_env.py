import subprocess
import sys
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import tumblebot.sim  # noqa: F401  (registers the environments)
from tumblebot.sim.errors import SimError, UnknownTaskError
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.env import OBS_FIELDS, OBS_INDEX, MotorModel, TumblerEnv
from tumblebot.sim.world.randomization import Randomization
from tumblebot.sim.world.tasks import TASK_NAMES, TASKS

ENV_IDS = [TASKS[t].env_id for t in TASK_NAMES]


def rollout(env: TumblerEnv, seed: int, actions: list[tuple[int, int]]
            ) -> tuple[list[np.ndarray], list[float], dict[str, Any]]:
    obs, _ = env.reset(seed=seed)
    observations: list[np.ndarray] = [obs]
    rewards: list[float] = []
    info: dict[str, Any] = {}
    for a in actions:
        obs, r, _, truncated, info = env.step(np.array(a))
        observations.append(obs)
        rewards.append(r)
        if truncated:
            break
    return observations, rewards, info


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_that_importing_tumblebot_sim_registers_each_task_with_gymnasium(env_id: str) -> None:
    env = gym.make(env_id)
    try:
        assert env.action_space == gym.spaces.MultiDiscrete([3, 3])
        assert env.observation_space.shape == (len(OBS_FIELDS),)
    finally:
        env.close()


@pytest.mark.parametrize("task", TASK_NAMES)
def test_that_gymnasium_and_sb3_env_checkers_pass(task: str) -> None:
    env = TumblerEnv(task=task)
    try:
        gym_check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=True)
    finally:
        env.close()


@pytest.mark.parametrize("task", TASK_NAMES)
def test_that_an_episode_is_20_steps_and_reports_the_final_state_reward(task: str) -> None:
    env = TumblerEnv(task=task)
    try:
        env.reset(seed=3)
        for t in range(20):
            _, _, terminated, truncated, info = env.step(np.array([2, 2]))
            assert not terminated
            assert truncated == (t == 19)
        assert info["final_R"] == info["R"]
        assert set(info) >= {"reward_state", "reward_progress", "design"}
    finally:
        env.close()


def test_that_a_final_weight_alone_rewards_exactly_the_final_state_r() -> None:
    # state_weight = progress_weight = 0, final_weight = 1: the return is what evaluation scores
    shaped, final = (TumblerEnv(task="nav-flat", state_weight=w, progress_weight=5 * w, final_weight=1 - w)
                     for w in (1.0, 0.0))
    try:
        actions = [(2, 2), (2, 0), (0, 2), (1, 1)] * 5
        _, shaped_rewards, shaped_info = rollout(shaped, 4, actions)
        _, rewards, info = rollout(final, 4, actions)
        assert info["final_R"] == shaped_info["final_R"]  # the same episode
        assert rewards[:-1] == [0.0] * 19 and rewards[-1] == info["final_R"]
        assert sum(shaped_rewards) != pytest.approx(info["final_R"])
    finally:
        shaped.close()
        final.close()


@pytest.mark.parametrize("task", TASK_NAMES)
def test_that_the_same_seed_gives_the_same_episode_bit_for_bit(task: str) -> None:
    actions = [(2, 2), (2, 1), (0, 2), (1, 1), (2, 0)] * 4
    a, b = TumblerEnv(task=task), TumblerEnv(task=task)
    try:
        obs_a, rew_a, _ = rollout(a, 7, actions)
        obs_b, rew_b, _ = rollout(b, 7, actions)
        assert all(np.array_equal(x, y) for x, y in zip(obs_a, obs_b, strict=True))
        assert rew_a == rew_b
        obs_c, _, _ = rollout(a, 8, actions)
        assert not np.array_equal(obs_a[0], obs_c[0])
    finally:
        a.close()
        b.close()


def test_that_reusing_an_env_does_not_change_an_episode() -> None:
    env = TumblerEnv(task="nav-flat")
    try:
        first, _, _ = rollout(env, 11, [(2, 2)] * 5)
        rollout(env, 12, [(0, 1)] * 5)
        again, _, _ = rollout(env, 11, [(2, 2)] * 5)
        assert all(np.array_equal(x, y) for x, y in zip(first, again, strict=True))
    finally:
        env.close()


@pytest.mark.parametrize("motor_model", ["dc", "velocity"])
def test_that_restoring_a_snapshot_replays_the_same_future(motor_model: MotorModel) -> None:
    env = TumblerEnv(task="incline", motor_model=motor_model)
    try:
        env.reset(seed=5)
        for a in [(2, 2), (2, 1), (1, 1)]:
            env.step(np.array(a))
        snap = env.snapshot()
        actions = [(2, 2), (0, 2), (2, 2), (1, 1), (2, 0)]
        first = [env.step(np.array(a)) for a in actions]
        env.restore(snap)
        env.step(np.array((0, 0)))  # a different branch in between changes nothing
        env.step(np.array((2, 0)))
        observation = env.restore(snap)
        env.release(snap)
        again = [env.step(np.array(a)) for a in actions]
        assert np.array_equal(observation[7:], np.array([0.0, 0.0], dtype=np.float32))  # the command at the snapshot
        for (o1, r1, *_), (o2, r2, *_) in zip(first, again, strict=True):
            assert np.array_equal(o1, o2) and r1 == r2
    finally:
        env.close()


def test_that_episodes_with_the_same_seed_share_their_randomness_across_designs() -> None:
    env = TumblerEnv(task="nav-flat")
    try:
        small = Design(0.189, 0.102, 0.084, 0.1)
        large = Design(0.3, 0.25, 0.2, 0.25)
        _, info_small = env.reset(seed=5, options={"design": small})
        _, info_large = env.reset(seed=5, options={"design": large})
        assert info_small["design"] != info_large["design"]
        for key in ("spawn_yaw", "friction", "leg_angles"):
            assert info_small[key] == info_large[key]
        assert info_small["spawn_position"][:2] == info_large["spawn_position"][:2]
    finally:
        env.close()


def test_that_designs_are_drawn_over_the_bounds_when_randomised() -> None:
    env = TumblerEnv(task="distance-flat", randomization=Randomization())
    try:
        designs = {env.reset(seed=s)[1]["design"] for s in range(5)}
        assert len(designs) == 5
        assert all(Design.from_sequence(d).in_bounds() for d in designs)
    finally:
        env.close()


def test_that_training_can_draw_only_designs_that_can_tumble_without_shifting_the_world() -> None:
    every = TumblerEnv(task="distance-flat", randomization=Randomization())
    tumbling = TumblerEnv(task="distance-flat", randomization=Randomization(tumbling_designs_only=True))
    try:
        seeds = range(24)
        drawn = [Design.from_sequence(every.reset(seed=s)[1]["design"]) for s in seeds]
        assert not all(d.can_tumble for d in drawn)  # a quarter of the bounds cannot tumble
        infos = [tumbling.reset(seed=s)[1] for s in seeds]
        assert all(Design.from_sequence(i["design"]).can_tumble for i in infos)
        for s, d, info in zip(seeds, drawn, infos, strict=True):
            if d.can_tumble:  # the first draw is kept when it can tumble
                assert info["design"] == d.as_tuple()
            # the world is the same whichever design was drawn (common random numbers)
            assert info["leg_angles"] == every.reset(seed=s)[1]["leg_angles"]
    finally:
        every.close()
        tumbling.close()


def test_that_the_observation_layout_is_position_quaternion_and_last_command() -> None:
    env = TumblerEnv(task="nav-flat")
    try:
        env.reset(seed=0)
        obs, *_ = env.step(np.array([0, 2]))
        assert obs[OBS_INDEX["cmd_right"]] == -1.0
        assert obs[OBS_INDEX["cmd_left"]] == 1.0
        q = obs[OBS_INDEX["qx"]:OBS_INDEX["qw"] + 1]
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-5)
    finally:
        env.close()


@pytest.mark.parametrize("bad", [[3, 0], [1], [-1, 1], "forward"])
def test_that_an_invalid_action_raises_a_clear_error(bad: object) -> None:
    env = TumblerEnv(task="nav-flat")
    try:
        env.reset(seed=0)
        with pytest.raises(SimError, match="action"):
            env.step(bad)
    finally:
        env.close()


def test_that_an_unknown_task_is_one_clear_error() -> None:
    with pytest.raises(UnknownTaskError, match="unknown task 'swim'"):
        TumblerEnv(task="swim")


@pytest.mark.parametrize("motor_model", ["dc", "velocity"])
def test_that_both_legs_forward_moves_the_robot_along_plus_x_in_the_distance_task(motor_model: str) -> None:
    env = TumblerEnv(task="distance-flat", randomization=Randomization.off(), motor_model=motor_model)  # type: ignore[arg-type]
    try:
        _, _, info = rollout(env, 0, [(2, 2)] * 20)
        assert info["final_R"] > 1.0
    finally:
        env.close()


def test_that_forward_climbs_the_incline() -> None:
    env = TumblerEnv(task="incline", randomization=Randomization.off())
    try:
        observations, _, info = rollout(env, 0, [(2, 2)] * 20)
        px, pz = observations[-1][0], observations[-1][2]
        assert info["final_R"] > 0.3
        assert pz > 0.2 * px  # on the 15° ramp (tan 15° ≈ 0.27), not beside it
    finally:
        env.close()


def test_that_rgb_array_rendering_works_headless() -> None:
    env = TumblerEnv(task="nav-terrain", render_mode="rgb_array", render_size=(64, 48))
    try:
        env.reset(seed=0)
        frame = env.render()
        assert frame.shape == (48, 64, 3)
        assert frame.dtype == np.uint8
        assert frame.std() > 5  # not a blank image
    finally:
        env.close()


def test_that_importing_tumblebot_imports_no_simulator() -> None:
    code = ("import sys, tumblebot, tumblebot.pi_agent.protocol; "
            "print(sorted(m for m in sys.modules if m.startswith(('tumblebot.sim', 'pybullet', 'gymnasium'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60).stdout
    assert out.strip() == "[]", out


def test_that_naming_the_module_in_the_id_registers_the_tasks() -> None:
    code = "import gymnasium as gym; env = gym.make('tumblebot.sim:tumblebot/NavFlat-v0'); print(env.spec.id)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120).stdout
    assert out.strip() == "tumblebot/NavFlat-v0"


def test_that_observation_is_what_step_returned_and_follows_advance() -> None:
    env = TumblerEnv(task="nav-flat")
    try:
        with pytest.raises(SimError, match="reset"):
            env.observation()
        env.reset(seed=3)
        obs, *_ = env.step(np.array([2, 0]))
        assert np.array_equal(env.observation(), obs)
        env.set_leg_commands(-1.0, 1.0)
        env.advance(120)
        moved = env.observation()
        assert list(moved[OBS_INDEX["cmd_right"]:]) == [-1.0, 1.0] and not np.array_equal(moved[:3], obs[:3])
    finally:
        env.close()
