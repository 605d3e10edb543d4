"""The twin's consistency check: its false-alarm rate, and that it catches injected bugs.

Pure simulation plays the twin here: the same start points and headings as a twin trial
set, and either the same controller (the check must pass, at a rate of at least 1 − α) or
one with a bug injected where the deployed chain could have one (it must fail)."""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial

import numpy as np
import pytest

from tumblebot.host.twin import combined_p, consistency_test, upper_tail_p
from tumblebot.sim.control.policy import OnnxPolicy, bundled_policy
from tumblebot.sim.evaluation.evaluate import episode_seed
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.env import TumblerEnv
from tumblebot.sim.world.randomization import Randomization

XI3 = Design(0.292, 0.129, 0.098, 0.136)
STARTS = [(1.5 * math.cos(a), 1.5 * math.sin(a), a + 1.0) for a in (0.3, 2.4, 4.5)]  # 3 trials, the 1.5 m circle
Act = Callable[[np.ndarray], np.ndarray]


def test_that_the_false_alarm_rate_is_at_most_alpha_for_three_trials() -> None:
    rng = np.random.default_rng(0)
    n, alpha, reps = 16, 0.01, 20_000
    rejected = 0
    for _ in range(reps):  # under consistency each per-trial p is uniform on {1/17, …, 1}
        ps = list(rng.integers(1, n + 2, size=3) / (n + 1))
        rejected += combined_p(ps, [n] * 3) < alpha
    assert rejected / reps <= alpha * 1.2  # exact null: at most α, give or take the Monte Carlo error


def test_that_a_twin_better_than_simulation_is_no_alarm() -> None:
    sim = [[0.1, 0.2, 0.25, 0.3, 0.5, 0.9, 1.4, 2.0]] * 3
    assert consistency_test([0.01, 0.02, 0.03], sim)["consistent"]  # the case a test of means rejected


def test_that_errors_beyond_every_simulation_are_an_alarm() -> None:
    sim = [[0.1, 0.2, 0.25, 0.3, 0.5, 0.9, 1.4, 2.0, 0.15, 0.22, 0.31, 0.4, 0.12, 0.18, 0.26, 0.33]] * 3
    assert upper_tail_p(3.0, sim[0]) == pytest.approx(1 / 17)
    assert not consistency_test([2.5, 3.0, 2.8], sim)["consistent"]


def _errors(act: Act, seeds: list[int], start: tuple[float, float, float], env: TumblerEnv,
            command_lasts: float = 1.0, reset: Callable[[], None] | None = None) -> list[float]:
    """Final distances to the goal; ``command_lasts`` < 1 drives each decision's command for
    only that fraction of its second, then stops the legs (a keepalive that never arrives,
    so the firmware's watchdog cuts every command short)."""
    out = []
    for s in seeds:
        obs, _ = env.reset(seed=s, options={"start_xy": start[:2], "start_yaw": start[2]})
        if reset is not None:  # a policy with memory starts every episode afresh
            reset()
        info: dict[str, object] = {}
        if command_lasts >= 1.0:
            for _ in range(env.episode_steps):
                obs, _, _, truncated, info = env.step(act(obs))
                if truncated:
                    break
            fx, fy = info["final_position"][:2]  # type: ignore[index]
        else:
            on = round(env.substeps * command_lasts)
            for _ in range(env.episode_steps):
                right, left = (np.asarray(act(obs)) - 1.0).tolist()
                env.set_leg_commands(right, left)
                env.advance(on)
                env.set_leg_commands(0.0, 0.0)
                env.advance(env.substeps - on)
                (px, py, pz), q = env.base_pose()
                obs = np.array([px, py, pz, *q, right, left], dtype=np.float32)
            fx, fy = obs[:2]
        out.append(math.hypot(fx, fy))
    return out


def _check(twin_act: Act, policy: OnnxPolicy, rep: int = 0, command_lasts: float = 1.0) -> dict[str, object]:
    env = TumblerEnv(task="nav-flat", design=XI3, randomization=Randomization(design=False))
    try:
        twin, sims = [], []
        for trial, start in enumerate(STARTS):
            reset = partial(policy.reset, XI3.as_tuple())
            twin += _errors(twin_act, [episode_seed(10_000 + rep, trial)], start, env, command_lasts, reset)
            sims.append(_errors(policy.act, [episode_seed(j, trial) for j in range(16)], start, env, reset=reset))
        return consistency_test(twin, sims)
    finally:
        env.close()


@pytest.fixture(scope="module")
def policy() -> OnnxPolicy:
    return OnnxPolicy(bundled_policy("nav-flat"), task="nav-flat")


@pytest.mark.slow
def test_that_pure_simulation_against_itself_passes(policy: OnnxPolicy) -> None:
    verdicts = [bool(_check(policy.act, policy, rep)["consistent"]) for rep in range(6)]
    assert sum(verdicts) >= 5, verdicts  # at α = 0.01, two false alarms in six happen once in ~700 sets


@pytest.mark.slow
@pytest.mark.parametrize("bug", ["servos swapped", "a servo's direction reversed", "frame rotated 90°",
                                 "commands cut short by the watchdog"])
def test_that_an_injected_bug_is_caught(policy: OnnxPolicy, bug: str) -> None:
    quarter = np.array([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)])

    def rotate(obs: np.ndarray) -> np.ndarray:  # the rigid body's axes are defined 90° off the robot's
        x, y, z, w = obs[3:7]
        qx, qy, qz, qw = quarter
        q = np.array([qw * x + qx * w + qy * z - qz * y, qw * y - qx * z + qy * w + qz * x,
                      qw * z + qx * y - qy * x + qz * w, qw * w - qx * x - qy * y - qz * z])
        return np.array([obs[0], obs[1], obs[2], *q, obs[7], obs[8]], dtype=np.float32)

    acts: dict[str, Act] = {
        "servos swapped": lambda obs: policy.act(obs)[::-1],
        "a servo's direction reversed": lambda obs: np.array([2, 0]) + np.array([-1, 1]) * policy.act(obs),
        "frame rotated 90°": lambda obs: policy.act(rotate(obs)),
        "commands cut short by the watchdog": policy.act,
    }
    result = _check(acts[bug], policy, command_lasts=0.25 if bug == "commands cut short by the watchdog" else 1.0)
    assert not result["consistent"], result
