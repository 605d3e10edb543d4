"""Context-observation policies: imitation of goto, export, parity, and deployment.

The policy input built in training (:class:`ContextObservation`) and when deployed
(:class:`OnnxPolicy`) must be the same numbers, step by step; a tiny DAgger run exports
and runs in evaluation and the host like any other policy.
"""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tumblebot.cli import main
from tumblebot.sim.control.goto import FORWARD, NAVIGATION_TASKS, SPIN_POSITIVE, GotoController
from tumblebot.sim.control.policy import LAYOUTS, ObservationContext, OnnxPolicy, PolicyError, bundled_policy
from tumblebot.sim.evaluation.evaluate import Driver, evaluate
from tumblebot.sim.observation import CHOICE_LAYOUTS
from tumblebot.sim.world.design import THESIS_ROBOTS, Design
from tumblebot.sim.world.env import TumblerEnv
from tumblebot.sim.world.randomization import Randomization
from tumblebot.training.config import TrainConfig
from tumblebot.training.features import ContextObservation

XI3 = THESIS_ROBOTS["3"]


@pytest.fixture(scope="module")
def tiny_dagger(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = tmp_path_factory.mktemp("dagger") / "bc"
    assert main(["imitate", "--run-dir", str(run), "--iterations", "2", "--episodes", "3", "--updates", "30",
                 "--net-arch", "16,16", "--envs", "1"]) == 0
    return run


@pytest.fixture(scope="module")
def context_policy(tiny_dagger: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ctx") / "nav-flat.onnx"
    assert main(["export", str(tiny_dagger), "-o", str(out), "--eval-episodes", "0"]) == 0
    return out


def test_that_the_context_input_counts_down_and_remembers_the_previous_observation() -> None:
    context = ObservationContext("context", episode_steps=20)
    obs = [np.arange(9, dtype=np.float32) + 10 * k for k in range(3)]
    context.reset((0.2, 0.1, 0.1, 0.15))
    first, second, third = (context(o) for o in obs)
    assert first.shape == (len(LAYOUTS["context"]),)
    np.testing.assert_array_equal(first[:9], obs[0])
    np.testing.assert_allclose(first[9:13], (0.2, 0.1, 0.1, 0.15))
    assert (first[13], second[13], third[13]) == pytest.approx((1.0, 0.95, 0.90))
    np.testing.assert_array_equal(first[14:], obs[0])  # before the first step: the current one again
    np.testing.assert_array_equal(second[14:], obs[0])
    np.testing.assert_array_equal(third[14:], obs[1])
    context.reset((0.2, 0.1, 0.1, 0.15))
    assert context(obs[2])[13] == 1.0  # a new episode starts over


def test_that_a_context_input_without_a_design_is_one_clear_error() -> None:
    context = ObservationContext("context")
    with pytest.raises(PolicyError, match="call reset"):
        context(np.zeros(9))
    with pytest.raises(PolicyError, match="conditioned on the design"):
        context.reset(None)
    with pytest.raises(PolicyError, match="four positive lengths"):
        context.reset((0.2, 0.1, float("nan"), 0.1))
    context.reset((0.2, 0.1, 0.1, 0.1))
    with pytest.raises(PolicyError, match="not the thesis's 9"):
        context(np.zeros(23))


def test_that_training_builds_the_same_input_the_deployed_policy_builds() -> None:
    design = Design(0.25, 0.15, 0.12, 0.2)
    wrapped = ContextObservation(TumblerEnv(task="nav-flat", design=design))
    bare = TumblerEnv(task="nav-flat", design=design)
    deployed = ObservationContext("context")
    rng = np.random.default_rng(3)
    try:
        x, _ = wrapped.reset(seed=11)
        obs, _ = bare.reset(seed=11)
        deployed.reset(design.as_tuple())
        for _ in range(20):
            np.testing.assert_array_equal(x, deployed(obs))
            action = rng.integers(0, 3, 2)
            x, _, terminated, truncated, _ = wrapped.step(action)
            obs, *_ = bare.step(action)
        assert terminated and not truncated  # the steps left are observed: the end is terminal
    finally:
        wrapped.close()
        bare.close()


@pytest.mark.parametrize("driver", ["goto", "random"])
def test_that_the_memory_input_holds_gotos_own_motion_estimates_at_every_step(driver: str) -> None:
    """The memory layout's last three numbers are what goto has learnt by that step,
    whoever drives: they are rebuilt from the commands the observations carry."""
    env = TumblerEnv(task="nav-flat", design=XI3)
    memory, context = ObservationContext("memory"), ObservationContext("context")
    goto = GotoController()
    rng = np.random.default_rng(5)
    try:
        for seed in range(3):
            obs, _ = env.reset(seed=seed)
            memory.reset(XI3.as_tuple())
            context.reset(XI3.as_tuple())
            goto.reset()
            for step in range(20):
                x = memory(obs)
                action = goto.act(obs, step)
                if driver == "random":
                    action = (int(rng.integers(3)), int(rng.integers(3)))
                    goto.taken(action)
                assert x.shape == (len(LAYOUTS["memory"]),)
                np.testing.assert_array_equal(x[:len(LAYOUTS["context"])], context(obs))  # context, then memory
                np.testing.assert_allclose(x[-3:], goto.motion.as_array(), rtol=1e-6, atol=1e-7)
                obs, *_ = env.step(np.array(action))
    finally:
        env.close()


@pytest.mark.parametrize("driver", ["goto", "random"])
def test_that_the_residual_input_holds_the_action_goto_would_take_at_every_step(driver: str) -> None:
    """The residual layout is the memory layout, then goto's own choice for this step,
    told what was actually done before (whoever drives)."""
    env = TumblerEnv(task="nav-flat", design=XI3)
    residual, memory = ObservationContext("residual"), ObservationContext("memory")
    goto = GotoController()
    rng = np.random.default_rng(6)
    try:
        for seed in range(3):
            obs, _ = env.reset(seed=seed)
            residual.reset(XI3.as_tuple())
            memory.reset(XI3.as_tuple())
            goto.reset()
            for step in range(20):
                x = residual(obs)
                action = goto.act(obs, step)
                assert x.shape == (len(LAYOUTS["residual"]),)
                np.testing.assert_allclose(x[:len(LAYOUTS["memory"])], memory(obs), rtol=1e-6, atol=1e-7)
                assert (int(x[-2]), int(x[-1])) == action
                if driver == "random":
                    action = (int(rng.integers(3)), int(rng.integers(3)))
                    goto.taken(action)
                obs, *_ = env.step(np.array(action))
    finally:
        env.close()


def test_that_the_residual_layouts_goto_is_pinned_to_the_settings_it_was_trained_with() -> None:
    from tumblebot.defaults import OBSERVATION_LAYOUTS
    from tumblebot.sim.control.goto import GotoConfig
    from tumblebot.sim.control.policy import DUAL_GOTO, RESIDUAL_GOTO

    assert tuple(LAYOUTS) == OBSERVATION_LAYOUTS
    assert GotoConfig(**RESIDUAL_GOTO) == GotoConfig(spin_steps_left=2)
    assert GotoConfig(**DUAL_GOTO) == GotoConfig(turn_tolerance=0.3, spin_steps_left=4)


def _assert_input_ends_with_a_gotos_action(layout: str, shorter: str, settings: dict[str, Any], design: Design,
                                           seeds: int, drive: Any) -> int:
    """Drive ``seeds`` episodes of ``design``; at every step the ``layout`` input must be the
    ``shorter`` layout's input, then the action of a goto with ``settings`` told what was
    actually done (``drive(x, its_action)`` picks that). How often its action differed from
    the first goto's."""
    from tumblebot.sim.control.goto import GotoConfig
    from tumblebot.sim.observation import field_index

    env = TumblerEnv(task="nav-flat", design=design)
    longer, prefix = ObservationContext(layout), ObservationContext(shorter)
    goto = GotoController(GotoConfig(**settings))
    first = field_index(layout, "goto_right")
    differ = 0
    try:
        for seed in range(seeds):
            obs, _ = env.reset(seed=seed)
            for context in (longer, prefix):
                context.reset(design.as_tuple())
            goto.reset()
            for step in range(20):
                x = longer(obs)
                assert x.shape == (len(LAYOUTS[layout]),) == (len(LAYOUTS[shorter]) + 2,)
                np.testing.assert_allclose(x[:len(LAYOUTS[shorter])], prefix(obs), rtol=1e-6, atol=1e-7)
                action = goto.act(obs, step)
                assert (int(x[-2]), int(x[-1])) == action
                differ += (int(x[first]), int(x[first + 1])) != action
                taken = drive(x, action)
                goto.taken(taken)
                obs, *_ = env.step(np.array(taken))
    finally:
        env.close()
    return differ


@pytest.mark.parametrize("driver", ["second goto", "random"])
def test_that_the_dual_input_holds_the_actions_of_both_gotos_at_every_step(driver: str) -> None:
    """The dual layout is the residual layout, then the second goto's choice for this step;
    both are told what was actually done before (whoever drives)."""
    from tumblebot.sim.control.policy import DUAL_GOTO

    rng = np.random.default_rng(7)

    def drive(x: np.ndarray, action: tuple[int, int]) -> tuple[int, int]:
        return action if driver == "second goto" else (int(rng.integers(3)), int(rng.integers(3)))

    differ = _assert_input_ends_with_a_gotos_action("dual", "residual", DUAL_GOTO, XI3, 4, drive)
    assert differ > 0, "the two gotos never disagreed: the second is not the second setting"


def _choice_file(folder: Path, layout: str = "dual") -> Path:
    """A goto choice from a made-up sweep of ``layout``'s two gotos: the second setting
    ahead where the legs are long."""
    from tumblebot.sim.world.design import tumbling_designs
    from tumblebot.training.choice import GotoChoice

    designs = tumbling_designs(40, seed=1)
    records: list[dict[str, object]] = [{"design": list(d.as_tuple()), "layout": layout,
                                         "difference": 0.03 if d.reach > 1.4 else -0.03}
                                        for d in designs]
    if layout == "tri-plan":  # and the third setting ahead where they are short
        records = [{**r, "compared": [2, 3], "means": [0.0, 0.0], "errors": [0.01, 0.01],
                    "differences": [r["difference"], 0.03 if d.reach < 1.15 else -0.03]}
                   for r, d in zip(records, designs, strict=True)]
    path = folder / "choice.json"
    path.write_text(GotoChoice.fit(records).to_json())
    return path


@pytest.mark.parametrize("layout", ["memory", "residual", "dual", "dual-plan", "tri-plan"])
def test_that_a_memory_residual_or_dual_policy_exports_runs_and_matches_its_network(layout: str,
                                                                                   tmp_path: Path) -> None:
    run, out = tmp_path / layout, tmp_path / "nav-flat.onnx"
    choice = ["--choice", str(_choice_file(tmp_path, layout))] if layout in CHOICE_LAYOUTS else []
    assert main(["imitate", "--run-dir", str(run), "--iterations", "1", "--episodes", "2", "--updates", "10",
                 "--net-arch", "16,16", "--envs", "1", "--observation", layout, *choice]) == 0
    assert TrainConfig.load(run / "config.json").observation == layout
    assert main(["export", str(run), "-o", str(out), "--eval-episodes", "0"]) == 0
    card = json.loads(out.with_suffix(".json").read_text())
    assert card["observation"]["layout"] == layout and card["observation"]["fields"] == list(LAYOUTS[layout])
    assert "memory_spin_negative" in card["observation"]["note"]
    from stable_baselines3 import PPO

    model = PPO.load(run / "latest.zip", device="cpu")
    policy = OnnxPolicy(out, task="nav-flat")
    assert policy.layout == layout  # dual-plan has dual's fields: the card's name decides which gotos run
    x = np.random.default_rng(0).normal(size=(10_000, len(LAYOUTS[layout]))).astype(np.float32)
    if layout in ("residual", *CHOICE_LAYOUTS):  # goto's proposals are commands, 0, 1 or 2 per leg
        proposals = len(LAYOUTS[layout]) - len(LAYOUTS["memory"])
        x[:, -proposals:] = np.random.default_rng(1).integers(0, 3, size=(10_000, proposals))
    np.testing.assert_array_equal(policy.act_batch(x), model.predict(x, deterministic=True)[0])
    result = evaluate("nav-flat", XI3, Driver("onnx", str(out)), episodes=2, seed=0, workers=1)
    assert np.isfinite(result.mean_R)


def test_that_goto_learns_from_the_action_actually_taken() -> None:
    goto = GotoController()
    obs = np.array([1.0, 0.0, 0.05, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0], dtype=np.float32)
    goto.act(obs, 0)
    goto.taken(FORWARD)  # something else drove forward 0.4 m
    moved = obs.copy()
    moved[0] = 0.6
    before = dict(goto.spin_rate)
    goto.act(moved, 1)
    assert goto.step_length == pytest.approx(0.25 + 0.5 * (0.4 - 0.25))
    assert goto.spin_rate == before  # no spin was taken, so the spin estimates are unchanged
    assert SPIN_POSITIVE in goto.spin_rate


def test_that_an_imitation_run_is_a_training_run(tiny_dagger: Path) -> None:
    config = TrainConfig.load(tiny_dagger / "config.json")
    assert config.observation == "context" and config.net_arch == [16, 16]
    rows = (tiny_dagger / "imitation.csv").read_text().splitlines()
    assert rows[0].startswith("iteration,driver") and len(rows) == 3
    assert rows[1].split(",")[1] == "goto" and rows[2].split(",")[1] == "student"
    assert (tiny_dagger / "latest.zip").is_file() and (tiny_dagger / "episodes.csv").is_file()


def test_that_the_card_declares_the_context_layout(context_policy: Path) -> None:
    card = json.loads(context_policy.with_suffix(".json").read_text())
    assert card["observation"]["layout"] == "context"
    assert card["observation"]["fields"] == list(LAYOUTS["context"])
    assert "design" in card["observation"]["note"]
    policy = OnnxPolicy(context_policy, task="nav-flat")
    assert policy.needs_design
    with pytest.raises(PolicyError, match="conditioned on the design"):
        policy.reset()


def test_that_onnx_equals_sb3_on_10000_context_inputs(tiny_dagger: Path, context_policy: Path) -> None:
    from stable_baselines3 import PPO

    model = PPO.load(tiny_dagger / "latest.zip", device="cpu")
    policy = OnnxPolicy(context_policy, task="nav-flat")
    env = ContextObservation(TumblerEnv(task="nav-flat"))
    inputs, actions = [], []
    try:
        rng = np.random.default_rng(0)
        for seed in range(25):  # 500 inputs from real episodes, through the deployed path too
            x, _ = env.reset(seed=seed)
            policy.reset(env.unwrapped.design.as_tuple())  # type: ignore[attr-defined]
            obs = x[:9]
            for _ in range(20):
                inputs.append(x)
                actions.append(policy.act(obs))
                x, *_ = env.step(rng.integers(0, 3, 2))
                obs = x[:9]
    finally:
        env.close()
    expected, _ = model.predict(np.array(inputs), deterministic=True)
    np.testing.assert_array_equal(np.array(actions), expected)
    rng = np.random.default_rng(1)
    n = 9_500
    q = rng.normal(size=(n, 4))
    p = rng.normal(size=(n, 4))
    thesis = np.hstack([rng.uniform(-3, 3, (n, 2)), rng.uniform(0, 0.3, (n, 1)),
                        q / np.linalg.norm(q, axis=1, keepdims=True), rng.integers(-1, 2, (n, 2))])
    previous = np.hstack([thesis[:, 0:2] + rng.normal(0, 0.2, (n, 2)), rng.uniform(0, 0.3, (n, 1)),
                          p / np.linalg.norm(p, axis=1, keepdims=True), rng.integers(-1, 2, (n, 2))])
    designs = np.array([Design.sample(rng).as_tuple() for _ in range(n)])
    batch = np.vstack([np.array(inputs), np.hstack([thesis, designs, rng.integers(0, 21, (n, 1)) / 20, previous])])
    batch = batch.astype(np.float32)
    assert len(batch) >= 10_000
    expected, _ = model.predict(batch, deterministic=True)
    np.testing.assert_array_equal(policy.act_batch(batch), expected)


def test_that_evaluation_feeds_a_context_policy_the_design_and_is_worker_independent(context_policy: Path) -> None:
    one = evaluate("nav-flat", XI3, Driver("onnx", str(context_policy)), 6, seed=2, workers=1)
    two = evaluate("nav-flat", XI3, Driver("onnx", str(context_policy)), 6, seed=2, workers=2)
    np.testing.assert_array_equal(one.R, two.R)


def test_that_a_warm_start_from_an_imitation_run_keeps_its_input_and_network(tiny_dagger: Path,
                                                                             tmp_path: Path) -> None:
    run = tmp_path / "ft"
    settings = tmp_path / "finetune.json"  # sets a few keys; the inherited ones stay the source run's
    settings.write_text(json.dumps({"learning_rate": 5e-5, "n_steps": 32, "batch_size": 32}))
    assert main(["train", "--task", "nav-flat", "--init-from", str(tiny_dagger / "latest.zip"), "--steps", "64",
                 "--envs", "1", "--run-dir", str(run), "--checkpoint-every", "64", "--config", str(settings)]) == 0
    config = TrainConfig.load(run / "config.json")
    assert config.observation == "context" and config.net_arch == [16, 16] and config.tumbling_designs_only
    assert config.learning_rate == 5e-5 and config.n_steps == 32
    out = tmp_path / "ft.onnx"
    assert main(["export", str(run), "-o", str(out), "--eval-episodes", "0"]) == 0
    card = json.loads(out.with_suffix(".json").read_text())
    assert [r["run"] for r in card["lineage"]] == [tiny_dagger.name, "ft"]  # the card says where the weights came from
    assert card["lineage"][0]["steps"] == TrainConfig.load(tiny_dagger / "config.json").total_steps
    assert card["lineage_wall_seconds"] > 0


def test_that_imitation_refuses_tasks_that_are_not_navigation(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["imitate", "--task", "incline", "--run-dir", str(tmp_path / "x")]) == 2
    assert "not navigation" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_that_the_randomised_training_designs_reach_the_context_input() -> None:
    env = ContextObservation(TumblerEnv(task="nav-flat", randomization=Randomization(tumbling_designs_only=True)))
    try:
        seen = set()
        for seed in range(5):
            x, _ = env.reset(seed=seed)
            design = np.asarray(env.unwrapped.design.as_tuple(), dtype=np.float32)  # type: ignore[attr-defined]
            np.testing.assert_array_equal(design, x[9:13])
            seen.add(tuple(x[9:13]))
        assert len(seen) == 5
    finally:
        env.close()


def test_that_the_thesis_observation_policies_stay_bundled_under_their_own_name() -> None:
    from tumblebot.sim.optimize import study_drivers

    for task in NAVIGATION_TASKS:
        assert OnnxPolicy(bundled_policy(task, "thesis"), task=task).layout == "thesis"
    for task, controller in study_drivers("thesis-policy", ["nav-flat", "incline"]).items():
        assert OnnxPolicy(Path(controller.name), task=task).layout == "thesis"
    best = study_drivers("policy", ["nav-flat"])["nav-flat"]
    assert Path(best.name) == bundled_policy("nav-flat")


def test_that_a_study_records_that_it_used_the_thesis_observation_policies(tmp_path: Path) -> None:
    import optuna

    from tumblebot.sim.optimize import load_config, open_storage

    db = f"sqlite:///{tmp_path / 't.db'}"
    assert main(["optimize", "--tasks", "nav-flat", "--xi", "3", "--trials", "1", "--batch", "2",
                 "--storage", db, "--study", "t", "--thesis-policies", "--quiet"]) == 0
    config = load_config(optuna.load_study(study_name="t", storage=open_storage(db)))
    assert config is not None and config.controller == "thesis-policy"
    assert main(["optimize", "--tasks", "nav-flat", "--xi", "3", "--trials", "1", "--batch", "2",
                 "--storage", db, "--study", "t", "--gait", "goto", "--thesis-policies", "--quiet"]) == 2


def test_that_refining_toward_the_lookahead_teacher_keeps_goto_labels_before_the_window(
        tiny_dagger: Path, tmp_path: Path) -> None:
    run = tmp_path / "refined"
    assert main(["imitate", "--refine", str(tiny_dagger), "--run-dir", str(run), "--iterations", "1",
                 "--episodes", "2", "--updates", "5", "--envs", "1", "--lookahead", "3", "--draws", "1"]) == 0
    teacher = json.loads((run / "imitation.json").read_text())["teacher"]
    assert teacher == {"kind": "goto+search", "lookahead": 3, "draws": 1, "future": "drawn anew", "target": "best"}
    config = TrainConfig.load(run / "config.json")
    assert config.init_from == str(tiny_dagger / "latest.zip") and config.observation == "context"
    data = np.load(run / "dagger.npz")
    old = np.load(tiny_dagger / "dagger.npz")
    steps_left = LAYOUTS["context"].index("steps_left")
    kept = int(np.sum(old["inputs"][:, steps_left] > 3 / 20 + 1e-6))
    assert len(data["labels"]) == kept + 2 * 20  # the old states before the window, and two new episodes
    assert (run / "latest.zip").is_file() and (run / "student.onnx").is_file()
    searched = np.isfinite(data["values"][:, 0])
    assert searched.sum() == 2 * 3 and np.all(data["inputs"][searched, steps_left] <= 3 / 20 + 1e-6)
    np.testing.assert_array_equal(data["labels"][~searched], data["goto_labels"][~searched])


def _tiny_model(tmp_path: Path) -> Any:
    from tumblebot.training.ppo import build_vec_env, new_model

    config = TrainConfig(observation="context", net_arch=[32, 32], n_envs=1)
    return new_model(config, build_vec_env(config, seed=0), tmp_path)


@pytest.mark.parametrize("target", ["best", "expected"])
def test_that_the_expected_target_picks_the_best_action_on_average_over_states_that_look_alike(
        target: str, tmp_path: Path) -> None:
    """Two searched states the student cannot tell apart: in one (2, 2) is best, in the
    other (0, 0); (1, 1) is second best in both and best on average. ``best`` copies one of
    the two winners; ``expected`` picks (1, 1)."""
    import torch

    from tumblebot.training.imitation import ImitationConfig, Labelled, fit
    from tumblebot.training.lookahead import ALL_ACTIONS
    from tumblebot.training.ppo import StopRequest

    model = _tiny_model(tmp_path)
    x = np.repeat(np.random.default_rng(0).normal(size=(1, len(LAYOUTS["context"]))).astype(np.float32), 2, axis=0)
    values = np.zeros((2, 9), dtype=np.float32)
    values[:, ALL_ACTIONS.index((1, 1))] = 0.8
    values[0, ALL_ACTIONS.index((2, 2))] = values[1, ALL_ACTIONS.index((0, 0))] = 1.0
    data = Labelled(x, np.array([(2, 2), (0, 0)]), np.zeros(2, dtype=np.float32), np.array([(0, 2), (0, 2)]),
                    values)
    optimiser = torch.optim.Adam(model.policy.parameters(), lr=3e-3)
    fit(model, optimiser, data, ImitationConfig(updates=400, batch_size=32), 0, StopRequest(), target)
    action = tuple(int(v) for v in model.predict(x[:1], deterministic=True)[0][0])
    assert action in ({(2, 2), (0, 0), (2, 0), (0, 2)} if target == "best" else {(1, 1)})


def test_that_the_expected_target_keeps_gotos_action_where_no_action_is_better_on_average(tmp_path: Path) -> None:
    import torch

    from tumblebot.training.imitation import ImitationConfig, Labelled, fit
    from tumblebot.training.ppo import StopRequest

    model = _tiny_model(tmp_path)
    x = np.random.default_rng(1).normal(size=(1, len(LAYOUTS["context"]))).astype(np.float32)
    data = Labelled(x, np.array([(2, 2)]), np.zeros(1, dtype=np.float32), np.array([(2, 0)]),
                    np.full((1, 9), 0.5, dtype=np.float32))  # every action scores the same
    optimiser = torch.optim.Adam(model.policy.parameters(), lr=3e-3)
    fit(model, optimiser, data, ImitationConfig(updates=300, batch_size=8), 0, StopRequest(), "expected")
    assert tuple(int(v) for v in model.predict(x, deterministic=True)[0][0]) == (2, 0)


def _final_after(env: TumblerEnv, snap: Any, goto: GotoController, obs: np.ndarray, first: tuple[int, int]) -> float:
    """Final R from ``snap`` (step 17) when ``first`` is taken, then goto to the end."""
    env.restore(snap)
    follower = copy.deepcopy(goto)
    follower.act(obs, 17)
    follower.taken(first)
    o, *_ = env.step(np.array(first))
    info: dict[str, Any] = {}
    for step in (18, 19):
        o, _, _, _, info = env.step(np.array(follower.act(o, step)))
    return float(info["final_R"])


def _drive_to_step_17(env: TumblerEnv, seed: int) -> tuple[np.ndarray, GotoController]:
    obs, _ = env.reset(seed=seed)
    goto = GotoController()
    for step in range(17):
        obs, *_ = env.step(np.array(goto.act(obs, step)))
    return obs, goto


def test_that_the_lookahead_search_never_picks_an_action_worse_than_gotos() -> None:
    from tumblebot.training.lookahead import _search

    env = TumblerEnv(task="nav-flat", design=XI3)
    try:
        for seed in range(3):
            obs, goto = _drive_to_step_17(env, seed)  # goto drives to the last three steps
            snap = env.snapshot()
            chosen = _search(env, goto, obs, 17)
            plain = copy.deepcopy(goto).act(obs, 17)
            # the same future (the snapshot holds the noise to come): the search is at least goto
            assert _final_after(env, snap, goto, obs, chosen) >= _final_after(env, snap, goto, obs, plain) - 1e-9
            env.release(snap)
    finally:
        env.close()


def test_that_reseeding_the_motor_noise_draws_a_future_other_than_the_episodes_own() -> None:
    env = TumblerEnv(task="nav-flat", design=XI3)
    try:
        obs, goto = _drive_to_step_17(env, 0)
        snap = env.snapshot()
        own = [_final_after(env, snap, goto, obs, (2, 2)) for _ in range(2)]
        assert own[0] == own[1]  # restore brings back the episode's own noise to come
        drawn = []
        for draw in range(3):
            env.restore(snap)
            env.reseed_motor_noise([7, draw])
            follower = copy.deepcopy(goto)
            follower.act(obs, 17)
            o, *_ = env.step(np.array((2, 2)))
            drawn.append(float(o[0]))
        assert len(set(drawn)) == 3  # three draws, three futures
        env.release(snap)
    finally:
        env.close()


def test_that_the_search_over_drawn_futures_is_deterministic_and_keeps_the_episode_unchanged() -> None:
    from tumblebot.training.lookahead import _search

    env = TumblerEnv(task="nav-flat", design=XI3)
    try:
        obs, goto = _drive_to_step_17(env, 1)
        snap = env.snapshot()
        first = _search(env, goto, obs, 17, draws=2, seed=5)
        assert _search(env, goto, obs, 17, draws=2, seed=5) == first  # the same draws, the same label
        after_search = env.step(np.array((2, 2)))[0]
        env.restore(snap)
        untouched = env.step(np.array((2, 2)))[0]
        np.testing.assert_array_equal(after_search, untouched)  # the episode's own future is restored
        env.release(snap)
    finally:
        env.close()


def test_that_imitate_refuses_a_negative_number_of_draws(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["imitate", "--refine", "runs/none", "--run-dir", "x", "--draws", "-1"])
    assert stop.value.code == 2
    assert "--draws: -1 must be an integer from 0 to 1000" in capsys.readouterr().err


def test_that_a_card_reuses_gait_baselines_only_when_they_reproduce(tiny_dagger: Path, tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    from tumblebot.training import card_eval

    first, second = tmp_path / "a" / "nav-flat.onnx", tmp_path / "b" / "nav-flat.onnx"
    # by default a design behind is measured again on five times the episodes, at most 240
    assert (card_eval._confirm(None, 2), card_eval._confirm(None, 100), card_eval._confirm(3, 2)) == (10, 240, 3)
    assert main(["export", str(tiny_dagger), "-o", str(first), "--eval-episodes", "2", "--confirm-episodes", "4"]) == 0
    card = json.loads(first.with_suffix(".json").read_text())
    hand = card["evaluation"]["against_hand_written"]
    assert len(hand["fixed"]["rows"]) == 12
    assert set(hand["fixed"]["rows"][0]["hand_written"]) == {"goto", "plan", "plan-short"}
    assert len(hand["fresh"]["rows"]) == 24 and hand["fresh"]["design_seed"] == 104729  # drawn afresh
    fresh = card_eval.fresh_designs("nav-flat")
    for comparison in hand.values():  # behind at first: measured again on fresh episodes
        assert comparison["confirm_episodes"] == 4
        assert set(comparison["behind"]) <= set(comparison["screened_behind"])
        again = [r for r in comparison["rows"] if "confirmation" in r]
        assert {r["label"] for r in again} == set(comparison["screened_behind"])
        assert all(r["confirmation"]["episodes"] == 4 and r["confirmation"]["seed"] == 1000 for r in again)
    # the baselines are the card's two designs': the comparisons' design sets can be small from here on
    monkeypatch.setattr(card_eval, "NAV_GRID", dict(list(card_eval.NAV_GRID.items())[:2]))
    monkeypatch.setattr(card_eval, "fresh_designs", lambda task: dict(list(fresh.items())[:2]))
    assert main(["export", str(tiny_dagger), "-o", str(second), "--eval-episodes", "2", "--confirm-episodes", "0",
                 "--baselines-from", str(first.with_suffix(".json"))]) == 0
    again = json.loads(second.with_suffix(".json").read_text())["evaluation"]["designs"]["xi3_robot"]
    assert again["baselines_reused_from_previous_card"] is True
    assert again["baselines"] == card["evaluation"]["designs"]["xi3_robot"]["baselines"]
    assert again["p_vs_best_fixed_gait"] == pytest.approx(card["evaluation"]["designs"]["xi3_robot"]
                                                          ["p_vs_best_fixed_gait"], rel=1e-6, abs=1e-12)
    stale = json.loads(first.with_suffix(".json").read_text())
    best = stale["evaluation"]["designs"]["xi3_robot"]["best_fixed_gait"]
    stale["evaluation"]["designs"]["xi3_robot"]["baselines"][best]["mean_R"] += 0.01  # no longer reproduces
    (tmp_path / "stale.json").write_text(json.dumps(stale))
    third = tmp_path / "c" / "nav-flat.onnx"
    assert main(["export", str(tiny_dagger), "-o", str(third), "--eval-episodes", "2", "--confirm-episodes", "0",
                 "--baselines-from", str(tmp_path / "stale.json")]) == 0
    rerun = json.loads(third.with_suffix(".json").read_text())["evaluation"]["designs"]["xi3_robot"]
    assert "baselines_reused_from_previous_card" not in rerun
    assert rerun["baselines"] == card["evaluation"]["designs"]["xi3_robot"]["baselines"]


def test_that_a_card_whose_observation_fields_are_not_a_list_is_one_clear_error(context_policy: Path,
                                                                                tmp_path: Path) -> None:
    bad = tmp_path / "nav-flat.onnx"
    bad.write_bytes(context_policy.read_bytes())
    card = json.loads(context_policy.with_suffix(".json").read_text())
    card["observation"]["fields"] = 7
    bad.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(PolicyError, match="no observation layout"):
        OnnxPolicy(bad)


def test_that_the_dual_plan_input_holds_plans_estimates_and_both_plan_gotos_actions() -> None:
    from tumblebot.sim.control.goto import GotoConfig
    from tumblebot.sim.observation import PLAN_DUAL_GOTO, PLAN_GOTO, field_index

    env = TumblerEnv(task="nav-flat", design=XI3)
    context = ObservationContext("dual-plan")
    first, second = GotoController(GotoConfig(**PLAN_GOTO)), GotoController(GotoConfig(**PLAN_DUAL_GOTO))
    step_length = field_index("dual-plan", "memory_step_length")
    try:
        obs, _ = env.reset(seed=3)
        context.reset(XI3.as_tuple())
        for step in range(20):
            x = context(obs)
            action, other = first.act(obs, step), second.act(obs, step)
            second.taken(action)
            assert (int(x[-4]), int(x[-3])) == action and (int(x[-2]), int(x[-1])) == other
            assert x[step_length] == pytest.approx(first.step_length, rel=1e-6)  # plan's memory: 0.25
            obs, *_ = env.step(np.array(action))
    finally:
        env.close()


def test_that_the_tri_plan_input_holds_the_dual_plan_input_then_the_short_legged_settings_action() -> None:
    from tumblebot.sim.observation import PLAN_SHORT_GOTO, field_index

    short_legs = Design(0.259, 0.227, 0.099, 0.132)  # l/r 1.07: the third setting gains most on such bodies
    plan = field_index("tri-plan", "goto_right")

    def drive(x: np.ndarray, action: tuple[int, int]) -> tuple[int, int]:
        return int(x[plan]), int(x[plan + 1])  # plan's: the teacher drives, the third is told

    differ = _assert_input_ends_with_a_gotos_action("tri-plan", "dual-plan", PLAN_SHORT_GOTO, short_legs, 3, drive)
    assert differ > 0, "plan and the third goto never disagreed: the third is not its own setting"


@pytest.mark.parametrize("named", ["dual", ["dual-plan"], "thesis", "warp"])
def test_that_a_card_naming_a_layout_gets_that_layout_or_one_clear_error(named: object, tmp_path: Path) -> None:
    import shutil

    from tumblebot.sim.control.policy import card_path

    source = Path(__file__).parents[2] / "training" / "checkpoints" / "plan-nav-flat" / "nav-flat.onnx"  # dual-plan
    policy = tmp_path / "p.onnx"
    shutil.copy(source, policy)
    card = json.loads(card_path(source).read_text())
    card["observation"]["layout"] = named
    card_path(policy).write_text(json.dumps(card))
    if named == "dual":
        assert OnnxPolicy(policy, task="nav-flat").layout == "dual"
    else:  # the wrong fields for the name, or no layout of that name (or not a name at all)
        with pytest.raises(PolicyError, match="none of the known layouts"):
            OnnxPolicy(policy, task="nav-flat")


def test_that_a_dagger_run_is_drawn_one_point_per_iteration(tiny_dagger: Path, tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tumblebot.training.curves import _plot_iterations, read_episodes

    data = read_episodes(tiny_dagger / "episodes.csv")
    fig, ax = plt.subplots()
    _plot_iterations(ax, tiny_dagger, data["steps"], data["final_R"], "C0")
    means = [c[0].get_ydata()[0] for c in ax.containers]  # an errorbar container: (data line, caps, bars)
    assert len(means) == 2  # one mean (with its interval) per iteration, not a moving average
    assert means[0] == pytest.approx(float(np.mean(data["final_R"][data["steps"] == data["steps"].min()])))
    labels = [h.get_label() for h in ax.get_legend_handles_labels()[0]]
    assert "bc: goto drives (DAgger 0)" in labels
    plt.close(fig)
    assert main(["curve", str(tiny_dagger), "-o", str(tmp_path / "curve.png")]) == 0
    assert (tmp_path / "curve.png").stat().st_size > 1000


def test_that_a_falling_learning_rate_ends_each_fit_at_its_last_step_size(tiny_dagger: Path) -> None:
    import torch
    from stable_baselines3 import PPO

    from tumblebot.training.imitation import ImitationConfig, Labelled, fit
    from tumblebot.training.ppo import StopRequest

    model = PPO.load(tiny_dagger / "latest.zip", device="cpu")
    saved = np.load(tiny_dagger / "dagger.npz")
    data = Labelled(saved["inputs"], saved["labels"], saved["returns"], saved["goto_labels"], saved["values"])
    optimiser = torch.optim.Adam(model.policy.parameters(), lr=1e-3)
    seen: list[float] = []
    step = optimiser.step

    def record(*args: Any, **kwargs: Any) -> Any:
        seen.append(optimiser.param_groups[0]["lr"])
        return step(*args, **kwargs)

    optimiser.step = record  # type: ignore[method-assign]
    fit(model, optimiser, data, ImitationConfig(updates=5, batch_size=8, learning_rate_end=1e-4), 0, StopRequest())
    assert seen == pytest.approx([1e-3, 7.75e-4, 5.5e-4, 3.25e-4, 1e-4])
    seen.clear()
    fit(model, optimiser, data, ImitationConfig(updates=3, batch_size=8), 0, StopRequest())
    assert seen == pytest.approx([1e-4] * 3)  # without an end, the optimiser's own step size, as before


@pytest.mark.parametrize(("flag", "value"), [("--learning-rate-end", "0.01"), ("--learning-rate-end", "-1e-4"),
                                             ("--learning-rate", "nan")])
def test_that_imitate_refuses_a_bad_learning_rate_before_writing(flag: str, value: str, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    status: int | str | None
    try:  # a value that is no step size at all stops at the parser, the rest at the configuration
        status = main(["imitate", "--run-dir", str(run), "--iterations", "1", f"{flag}={value}"])
    except SystemExit as exc:
        status = exc.code
    assert status == 2
    assert re.search("learning.rate", capsys.readouterr().err)
    assert not run.exists()


def test_that_a_wrapped_environments_snapshot_brings_back_the_inputs_memory_with_the_simulation() -> None:
    from tumblebot.sim.evaluation.rollout import branch

    env = ContextObservation(TumblerEnv(task="nav-flat", design=XI3), "tri-plan")
    try:
        obs, _ = env.reset(seed=4)
        actions = [(2, 2), (2, 0), (2, 2), (0, 2), (2, 2), (1, 1)]
        for action in actions[:3]:
            obs, *_ = env.step(np.array(action))
        snap = env.snapshot()
        seen = [obs] + [env.step(np.array(a))[0] for a in actions[3:]]
        assert np.array_equal(env.restore(snap), seen[0])
        again = [env.step(np.array(a))[0] for a in actions[3:]]
        for first, second in zip(seen[1:], again, strict=True):
            np.testing.assert_array_equal(first, second)  # the memory fields too, not only the thesis's 9
        assert env.episode_steps == 20

        class Replay:
            def reset(self, seed: int, design: tuple[float, float, float, float]) -> None:
                pass

            def act(self, obs: np.ndarray, step: int) -> np.ndarray:
                return np.array((1, 1))

        stopped = branch(env, snap, actions[3], Replay(), 3)
        env.restore(snap)
        env.step(np.array(actions[3]))
        for _ in range(4, 19):
            env.step(np.array((1, 1)))
        assert env.step(np.array((1, 1)))[4]["final_R"] == stopped["final_R"]
        env.release(snap)
    finally:
        env.close()
