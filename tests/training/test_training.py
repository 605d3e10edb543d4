"""Training, resume, export parity, evaluation determinism and bad inputs (tiny budgets)."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import interruptible
from tumblebot.cli import main
from tumblebot.sim.control.policy import OBS_LAYOUT, OnnxPolicy, PolicyError
from tumblebot.sim.evaluation.evaluate import Driver, evaluate
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.env import OBS_FIELDS, TumblerEnv
from tumblebot.training.config import TrainConfig, TrainingError

XI3 = "0.292,0.129,0.098,0.136"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tumblebot.training.ppo import train

    run = tmp_path_factory.mktemp("run") / "nav"
    config = TrainConfig(task="nav-flat", total_steps=256, n_envs=1, n_steps=64, batch_size=64, n_epochs=2,
                         checkpoint_every=128, net_arch=[16, 16])
    train(config, run)
    return run


@pytest.fixture(scope="module")
def tiny_policy(tiny_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("policy") / "nav-flat.onnx"
    assert main(["export", str(tiny_run), "-o", str(out), "--eval-episodes", "0"]) == 0
    return out


def test_that_the_policy_layout_matches_the_environment() -> None:
    assert OBS_LAYOUT == OBS_FIELDS


def test_that_a_run_folder_holds_config_checkpoints_curve_and_episodes(tiny_run: Path) -> None:
    assert json.loads((tiny_run / "config.json").read_text())["task"] == "nav-flat"
    assert (tiny_run / "latest.zip").is_file()
    assert len(list((tiny_run / "checkpoints").glob("step_*.zip"))) >= 2
    assert (tiny_run / "learning_curve.png").stat().st_size > 1000
    with (tiny_run / "episodes.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) >= 10 and all(float(r["final_R"]) < 10 for r in rows)


def test_that_export_writes_one_self_contained_onnx_file_and_a_model_card(tiny_policy: Path) -> None:
    import onnx

    files = sorted(p.name for p in tiny_policy.parent.iterdir())
    assert files == ["nav-flat.json", "nav-flat.onnx"]  # no side .onnx.data
    onnx.checker.check_model(onnx.load(str(tiny_policy)), full_check=True)
    card = json.loads(tiny_policy.with_suffix(".json").read_text())
    assert card["task"] == "nav-flat"
    assert card["observation"]["fields"] == list(OBS_LAYOUT)
    assert card["training_steps"] >= 256
    assert card["seed"] == 0
    assert "motor_speed_sigma" in card["randomization"]


def test_that_a_step_checkpoint_exports_with_its_runs_config_and_wall_time(tiny_run: Path, tmp_path: Path,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    first = sorted((tiny_run / "checkpoints").glob("step_*.zip"))[0]
    steps = int(first.stem.split("_")[1])
    out = tmp_path / "early" / "nav-flat.onnx"
    assert main(["export", str(first), "-o", str(out), "--eval-episodes", "0"]) == 0
    card = json.loads(out.with_suffix(".json").read_text())
    assert card["task"] == "nav-flat" and card["training_steps"] == steps
    with (tiny_run / "episodes.csv").open() as fh:
        rows = [r for r in csv.DictReader(fh) if int(r["steps"]) <= steps]
    assert card["training_wall_seconds"] == float(rows[-1]["wall_seconds"])
    lone = tmp_path / "lone.zip"  # a checkpoint copied away from its run folder
    lone.write_bytes(first.read_bytes())
    assert main(["export", str(lone), "-o", str(tmp_path / "x.onnx")]) == 2
    assert "pass --task" in capsys.readouterr().err
    assert not (tmp_path / "x.onnx").exists()


def test_that_onnx_actions_equal_sb3_deterministic_predict_on_10000_observations(
        tiny_run: Path, tiny_policy: Path) -> None:
    from stable_baselines3 import PPO

    model = PPO.load(tiny_run / "latest.zip", device="cpu")
    policy = OnnxPolicy(tiny_policy, task="nav-flat")
    observations = []
    env = TumblerEnv(task="nav-flat")
    try:
        rng = np.random.default_rng(0)
        for seed in range(50):  # 1 000 observations from real episodes
            obs, _ = env.reset(seed=seed)
            for _ in range(20):
                observations.append(obs)
                obs, *_ = env.step(rng.integers(0, 3, 2))
    finally:
        env.close()
    rng = np.random.default_rng(1)
    n = 9_000  # and random states: positions, unit quaternions, commands
    q = rng.normal(size=(n, 4))
    random_states = np.hstack([rng.uniform(-3, 3, (n, 2)), rng.uniform(0, 0.3, (n, 1)),
                               q / np.linalg.norm(q, axis=1, keepdims=True), rng.integers(-1, 2, (n, 2))])
    batch = np.vstack([np.array(observations), random_states]).astype(np.float32)
    assert len(batch) >= 10_000
    expected, _ = model.predict(batch, deterministic=True)
    np.testing.assert_array_equal(policy.act_batch(batch), expected)
    one_at_a_time = np.array([policy.act(o) for o in batch[:200]])
    np.testing.assert_array_equal(one_at_a_time, expected[:200])


def test_that_evaluation_is_identical_whatever_the_number_of_workers(tiny_policy: Path) -> None:
    w = Design.parse(XI3)
    one = evaluate("nav-flat", w, Driver("onnx", str(tiny_policy)), 6, seed=3, workers=1)
    two = evaluate("nav-flat", w, Driver("onnx", str(tiny_policy)), 6, seed=3, workers=2)
    np.testing.assert_array_equal(one.R, two.R)
    other_seed = evaluate("nav-flat", w, Driver("onnx", str(tiny_policy)), 6, seed=4, workers=1)
    assert not np.array_equal(one.R, other_seed.R)


def test_that_evaluate_json_reports_mean_ci_e_and_episodes(tiny_policy: Path, capsys: pytest.CaptureFixture[str],
                                                          tmp_path: Path) -> None:
    csv_path = tmp_path / "episodes.csv"
    assert main(["evaluate", "--task", "nav-flat", "--design", XI3, "--episodes", "4", "--seed", "0",
                 "--policy", str(tiny_policy), "--xi", "3", "--csv", str(csv_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["episodes"] == 4
    assert out["ci95"][0] <= out["mean_R"] <= out["ci95"][1]
    assert out["e"] == pytest.approx(5.22, abs=0.02)
    assert "mean_f" in out
    assert len(csv_path.read_text().splitlines()) == 5


def test_that_a_run_killed_mid_training_resumes_from_its_last_checkpoint(tmp_path: Path) -> None:
    run = tmp_path / "run"
    config = tmp_path / "config.json"
    config.write_text(json.dumps({"n_steps": 64, "batch_size": 64, "n_epochs": 1, "net_arch": [8]}))
    cmd = [sys.executable, "-m", "tumblebot.cli", "train", "--task", "distance-flat", "--steps", "100000",
           "--envs", "1", "--checkpoint-every", "128", "--config", str(config), "--run-dir", str(run)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 240
        while len(list((run / "checkpoints").glob("step_*.zip"))) < 2:
            assert time.monotonic() < deadline, "no checkpoint written"
            assert proc.poll() is None, "training exited early"
            time.sleep(0.2)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    from stable_baselines3 import PPO

    saved = PPO.load(run / "latest.zip", device="cpu").num_timesteps
    assert saved >= 128
    assert main(["train", "--resume", "--run-dir", str(run), "--steps", str(saved + 128)]) == 0
    resumed = PPO.load(run / "latest.zip", device="cpu").num_timesteps
    assert resumed >= saved + 128
    with (run / "episodes.csv").open() as fh:
        steps = [int(r["steps"]) for r in csv.DictReader(fh)]
    assert steps == sorted(steps)  # episodes past the checkpoint were dropped, not duplicated


@pytest.mark.parametrize(("args", "message"), [
    (["evaluate", "--task", "swim", "--design", XI3], "unknown task 'swim'"),
    (["evaluate", "--task", "nav-flat", "--design", XI3, "--policy", "missing.onnx"], "does not exist"),
    (["train", "--resume"], "--resume needs --run-dir"),
    (["train", "--resume", "--run-dir", "r", "--init-from", "x.zip"], "--init-from: options of a new run"),
    (["train", "--task", "incline", "--run-dir", "runs/never-made", "--init-from", "no-such.zip"],
     "does not exist"),
    (["export", "no-such-run", "-o", "x.onnx"], "no checkpoint"),
])
def test_that_bad_training_and_evaluation_input_is_one_clear_error(args: list[str], message: str) -> None:
    result = subprocess.run([sys.executable, "-m", "tumblebot.cli", *args], capture_output=True, text=True,
                            timeout=120, check=False)
    assert result.returncode == 2
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and message in lines[0], result.stderr
    assert not Path("runs/never-made").exists()  # a refused run leaves nothing behind


def test_that_a_corrupt_policy_file_is_refused(tiny_policy: Path, tmp_path: Path) -> None:
    bad = tmp_path / "nav-flat.onnx"
    bad.write_bytes(tiny_policy.read_bytes()[:-50])
    (tmp_path / "nav-flat.json").write_text(tiny_policy.with_suffix(".json").read_text())
    with pytest.raises(PolicyError, match="does not match its model card"):
        OnnxPolicy(bad)


def test_that_a_policy_for_another_task_or_layout_is_refused(tiny_policy: Path, tmp_path: Path) -> None:
    with pytest.raises(PolicyError, match="trained for task 'nav-flat', not 'incline'"):
        OnnxPolicy(tiny_policy, task="incline")
    other = tmp_path / "p.onnx"
    other.write_bytes(tiny_policy.read_bytes())
    card = json.loads(tiny_policy.with_suffix(".json").read_text())
    card["observation"]["fields"] = ["px", "py"]
    other.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(PolicyError, match="observation layout"):
        OnnxPolicy(other)


def test_that_evaluation_and_policies_do_not_import_torch() -> None:
    code = ("import sys, tumblebot.sim.evaluation.evaluate, tumblebot.sim.control.policy, tumblebot.cli; "
            "assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_that_a_warm_started_run_begins_from_the_other_runs_weights(tiny_run: Path, tmp_path: Path) -> None:
    import torch
    from stable_baselines3 import PPO

    from tumblebot.training.ppo import build_vec_env, new_model, train, warm_start

    source = PPO.load(tiny_run / "latest.zip", device="cpu")
    config = TrainConfig(task="incline", total_steps=64, n_envs=1, n_steps=64, batch_size=64, n_epochs=1,
                         net_arch=[16, 16], init_from=str(tiny_run / "latest.zip"))
    env = build_vec_env(config, seed=0)
    try:
        model = new_model(config, env, tmp_path)
        assert warm_start(model, tiny_run / "latest.zip") == source.num_timesteps
        mine, theirs = model.policy.state_dict(), source.policy.state_dict()
        assert mine.keys() == theirs.keys()
        assert all(torch.equal(mine[k], theirs[k]) for k in mine)
        wider = new_model(TrainConfig(task="incline", net_arch=[32, 32]), env, tmp_path)
        with pytest.raises(TrainingError, match="net_arch must match"):
            warm_start(wider, tiny_run / "latest.zip")
    finally:
        env.close()
    run = tmp_path / "incline"
    train(config, run)
    saved = json.loads((run / "config.json").read_text())
    assert saved["init_from"] == str(tiny_run / "latest.zip")
    assert saved["init_from_steps"] == source.num_timesteps


def test_that_a_warm_start_at_a_temperature_keeps_every_choice_but_explores(tiny_run: Path, tmp_path: Path) -> None:
    import torch
    from stable_baselines3 import PPO

    from tumblebot.training.ppo import build_vec_env, new_model, warm_start

    source = PPO.load(tiny_run / "latest.zip", device="cpu")
    config = TrainConfig(task="incline", n_envs=1, net_arch=[16, 16], warm_start_temperature=4.0)
    env = build_vec_env(config, seed=0)
    try:
        model = new_model(config, env, tmp_path)
        warm_start(model, tiny_run / "latest.zip", config.warm_start_temperature)
        obs = torch.as_tensor(np.stack([env.observation_space.sample() for _ in range(64)]))
        with torch.no_grad():
            hot, cold = (m.policy.get_distribution(obs) for m in (model, source))
            values = model.policy.predict_values(obs)
        assert torch.equal(hot.mode(), cold.mode())  # the deterministic policy is the same
        hot_entropy, cold_entropy = hot.entropy(), cold.entropy()
        assert hot_entropy is not None and cold_entropy is not None and (hot_entropy > cold_entropy).all()
        assert isinstance(hot.distribution, list) and isinstance(cold.distribution, list)
        for mine, theirs in zip(hot.distribution, cold.distribution, strict=True):
            assert isinstance(mine, torch.distributions.Categorical)
            assert isinstance(theirs, torch.distributions.Categorical)
            assert torch.allclose(mine.logits.softmax(-1), (theirs.logits / 4).softmax(-1), atol=1e-6)
        assert torch.equal(values, torch.zeros_like(values))
    finally:
        env.close()
    with pytest.raises(TrainingError, match=r"warm_start_temperature=0\.5 must be a number >= 1"):
        TrainConfig(warm_start_temperature=0.5)


def test_that_bad_training_configs_are_rejected() -> None:
    with pytest.raises(TrainingError, match="n_steps"):
        TrainConfig(n_steps=0)
    with pytest.raises(TrainingError, match="init_from=3"):
        TrainConfig(init_from=3)  # type: ignore[arg-type]
    with pytest.raises(TrainingError, match="unknown training config keys: lr"):
        TrainConfig.from_dict({"lr": 1})
    with pytest.raises(TrainingError, match="tumbling_designs_only='yes' must be true or false"):
        TrainConfig.from_dict({"tumbling_designs_only": "yes"})
    for key, value, message in [("gamma", 1.5, "must be at most 1"), ("learning_rate", float("nan"), "positive"),
                                ("final_weight", float("inf"), "number >= 0"), ("ent_coef", -0.1, "number >= 0"),
                                ("state_weight", True, "number >= 0"), ("gae_lambda", "1", "positive")]:
        with pytest.raises(TrainingError, match=f"{key}=.*{message}"):
            TrainConfig.from_dict({key: value})


def test_that_the_training_environments_follow_the_configs_design_distribution() -> None:
    from tumblebot.training.ppo import make_env

    for only in (False, True):
        env = make_env("nav-flat", randomization=TrainConfig(tumbling_designs_only=only).randomization())
        try:
            randomization = env.unwrapped.randomization  # type: ignore[attr-defined]
            assert randomization.tumbling_designs_only is only and randomization.design
        finally:
            env.close()


def test_that_the_training_environments_take_the_configs_reward_weights() -> None:
    from tumblebot.training.ppo import make_env

    config = TrainConfig(state_weight=0.0, progress_weight=0.5, final_weight=1.0)
    env = make_env(config.task, config.reward_weights())
    try:
        inner = env.unwrapped
        assert (inner.state_weight, inner.progress_weight, inner.final_weight) == (0.0, 0.5, 1.0)  # type: ignore[attr-defined]
    finally:
        env.close()


def test_that_ctrl_c_saves_a_checkpoint_and_exits_cleanly_regression_worker_hang(tmp_path: Path) -> None:
    """Ctrl-C reaches the whole process group; workers used to die first and hang the trainer."""
    run = tmp_path / "run"
    config = tmp_path / "config.json"
    config.write_text(json.dumps({"n_steps": 64, "batch_size": 64, "n_epochs": 1, "net_arch": [8]}))
    proc = subprocess.Popen([sys.executable, "-m", "tumblebot.cli", "train", "--task", "distance-flat", "--steps",
                             "100000", "--envs", "2", "--config", str(config), "--run-dir", str(run)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=interruptible)
    try:
        deadline = time.monotonic() + 120
        while not (run / "episodes.csv").exists() or len((run / "episodes.csv").read_text().splitlines()) < 3:
            assert time.monotonic() < deadline and proc.poll() is None, "training did not start"
            time.sleep(0.2)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=180)  # generous: CI machines may be loaded
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130
    assert "checkpoint saved" in err
    assert (run / "latest.zip").is_file()


def test_that_curve_follows_warm_starts_back_to_the_first_run(tmp_path: Path) -> None:
    from tumblebot.cli import main

    def run(name: str, init_from: str | None, steps: int) -> Path:
        folder = tmp_path / name
        folder.mkdir()
        rows = ["steps,final_R,shaped_return,wall_seconds"]
        rows += [f"{k * 20},{k / 100:.3f},1.0,{k}" for k in range(1, steps)]
        (folder / "episodes.csv").write_text("\n".join(rows) + "\n")
        config = {"init_from": init_from, "init_from_steps": 1000} if init_from else {}
        (folder / "config.json").write_text(json.dumps(config))
        return folder

    run("base", None, 80)
    run("tune", str(tmp_path / "base" / "latest.zip"), 60)
    last = run("tune2", str(tmp_path / "tune" / "checkpoints" / "step_1000.zip"), 40)
    out = tmp_path / "curve.png"
    assert main(["curve", str(last), "-o", str(out)]) == 0
    assert out.stat().st_size > 10_000
    from tumblebot.training.curves import lineage

    assert [f.name for f, _, _ in lineage(last)] == ["base", "tune", "tune2"]
    lonely = run("lonely", str(tmp_path / "gone" / "latest.zip"), 30)
    assert [m for _, _, m in lineage(lonely)] == [str(tmp_path / "gone" / "latest.zip")]  # said, not hidden
    assert main(["curve", str(tmp_path / "nothing"), "-o", str(out)]) == 2


# ----------------------------------------------------------------------------- a newcomer's commands
def _copy_run(run: Path, tmp_path: Path) -> Path:
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    return copy


def test_that_resuming_a_finished_run_twice_says_so_regression_runcallback_has_no_model(
        tiny_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _copy_run(tiny_run, tmp_path)
    before = (run / "latest.zip").read_bytes()
    for _ in range(2):  # the same command twice: the second crashed with AttributeError
        assert main(["train", "--resume", "--run-dir", str(run)]) == 0
        assert "already has 256 steps" in capsys.readouterr().out
    assert (run / "latest.zip").read_bytes() == before


@pytest.mark.parametrize(("extra", "message"), [
    (["--task", "incline"], "is a nav-flat run; resuming cannot change its task"),
    (["--envs", "3"], "--envs: options of a new run"),
    (["--observation", "context"], "--observation: options of a new run"),
    (["--seed", "4"], "--seed: options of a new run"),
])
def test_that_resume_refuses_options_of_a_new_run_regression_task_silently_ignored(
        tiny_run: Path, tmp_path: Path, extra: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    run = _copy_run(tiny_run, tmp_path)
    before = sorted(p.name for p in run.rglob("*"))
    assert main(["train", "--resume", "--run-dir", str(run), *extra]) == 2
    assert message in capsys.readouterr().err
    assert sorted(p.name for p in run.rglob("*")) == before


def test_that_resume_with_the_runs_own_task_is_accepted(tiny_run: Path, tmp_path: Path) -> None:
    run = _copy_run(tiny_run, tmp_path)
    assert main(["train", "--resume", "--run-dir", str(run), "--task", "nav-flat"]) == 0


def test_that_export_refuses_a_task_the_run_was_not_trained_for_regression_incline_card_on_nav_run(
        tiny_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "incline.onnx"
    assert main(["export", str(tiny_run), "--task", "incline", "-o", str(out), "--eval-episodes", "0"]) == 2
    assert "was trained for nav-flat" in capsys.readouterr().err
    assert not out.exists() and not out.with_suffix(".json").exists()
    terrain = tmp_path / "nav-terrain.onnx"  # a navigation run may serve both navigation tasks
    assert main(["export", str(tiny_run), "--task", "nav-terrain", "-o", str(terrain), "--eval-episodes", "0"]) == 0


def test_that_a_card_whose_task_contradicts_its_training_config_is_refused_regression_evaluate_accepted_it(
        tiny_policy: Path, tmp_path: Path) -> None:
    forged = tmp_path / "incline.onnx"
    forged.write_bytes(tiny_policy.read_bytes())
    card = json.loads(tiny_policy.with_suffix(".json").read_text())
    card["task"] = "incline"
    forged.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(PolicyError, match="its training config says 'nav-flat'"):
        OnnxPolicy(forged, task="incline")
    code = main(["evaluate", "--task", "incline", "--design", XI3, "--episodes", "2", "--seed", "0",
                 "--policy", str(forged)])
    assert code == 2


@pytest.mark.parametrize("command", ["export", "train"])
def test_that_an_output_folder_that_cannot_be_written_is_one_error_regression_read_only_traceback(
        tiny_run: Path, tmp_path: Path, command: str, capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where a folder should be\n")
    if command == "export":
        args = ["export", str(tiny_run), "-o", str(blocker / "p.onnx"), "--eval-episodes", "0"]
    else:
        args = ["train", "--steps", "64", "--run-dir", str(blocker / "run")]
    assert main(args) == 2
    assert "tumblebot: error" not in capsys.readouterr().out
    if os.geteuid() != 0:  # root writes through permissions; a read-only folder is checked as another user
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o555)
        target = ["-o", str(locked / "p.onnx")] if command == "export" else ["--run-dir", str(locked / "run")]
        assert main([*args[:2 if command == "export" else 3], *target]) == 2
    assert blocker.read_text() == "a file where a folder should be\n"


def test_that_init_from_a_missing_file_is_refused_before_anything_is_printed_regression_training_banner(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["train", "--init-from", str(tmp_path / "missing.zip"), "--run-dir", str(tmp_path / "run")]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "missing.zip does not exist" in err
    assert not (tmp_path / "run").exists()


def test_that_a_resumed_run_says_when_it_stops_past_its_total_regression_silent_overshoot(
        tiny_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _copy_run(tiny_run, tmp_path)
    assert main(["train", "--resume", "--run-dir", str(run), "--steps", "300"]) == 0
    out = capsys.readouterr().out
    assert "stopped at 320 steps, past the total of 300" in out and "whole rollouts of 64 steps" in out


def test_that_tensorboard_shows_the_final_state_R_regression_only_shaped_reward(tiny_run: Path) -> None:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator  # type: ignore[import-untyped]

    logs = sorted((tiny_run / "tb").rglob("events.out.tfevents.*"))
    assert logs
    tags: set[str] = set()
    for log in logs:
        acc = EventAccumulator(str(log))
        acc.Reload()
        tags.update(acc.Tags()["scalars"])
    assert "rollout/final_R_mean" in tags and "rollout/ep_rew_mean" in tags
