"""PPO training with checkpoints, resume, a progress bar and a learning curve.

A run lives in one folder::

    RUN/config.json          the TrainConfig (written once, read on --resume)
    RUN/latest.zip           the newest checkpoint (replaced atomically)
    RUN/checkpoints/         every checkpoint, named by environment steps
    RUN/episodes.csv         one row per finished episode: steps, final_R, shaped return
    RUN/tb/                  TensorBoard logs
    RUN/learning_curve.png   final-state R and shaped return vs steps (written at the end)

A run killed at any moment resumes from ``latest.zip`` (``train(..., resume=True)``),
losing at most one checkpoint interval; rows of ``episodes.csv`` past the checkpoint are
dropped on resume so the curve has no duplicates.
"""

from __future__ import annotations

import contextlib
import csv
import multiprocessing
import os
import shutil
import signal
import time
from collections import deque
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecMonitor
from tqdm import tqdm

from tumblebot.sim.world.env import TumblerEnv
from tumblebot.sim.world.physics import THESIS, PhysicsProfile
from tumblebot.sim.world.randomization import Randomization
from tumblebot.training.config import RewardWeights, TrainConfig, TrainingError
from tumblebot.training.features import ContextObservation, TumblerFeaturesExtractor

CSV_FIELDS = ("steps", "final_R", "shaped_return", "wall_seconds")


#: the bundled policies' reward shaping (TrainConfig's defaults)
DEFAULT_WEIGHTS = RewardWeights()


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped training; the checkpoint at ``steps`` is saved in ``run_dir``."""

    def __init__(self, steps: int, run_dir: Path) -> None:
        super().__init__(f"interrupted at {steps} steps; checkpoint saved. Continue with: "
                         f"tumblebot train --resume --run-dir {run_dir}")
        self.steps, self.run_dir = steps, run_dir


def make_env(task: str, weights: RewardWeights = DEFAULT_WEIGHTS,
             randomization: Randomization | None = None, physics: PhysicsProfile = THESIS,
             observation: str = "thesis", design: list[float] | None = None) -> gym.Env[np.ndarray, np.ndarray]:
    """Environment factory, run inside each worker process; ``observation`` ``"context"``
    ``"memory"`` or ``"residual"`` wraps it in :class:`ContextObservation`; ``design`` fixes the body."""
    from tumblebot.sim.world.design import Design

    torch.set_num_threads(1)
    if multiprocessing.parent_process() is not None:
        # Ctrl-C reaches the whole process group; only the trainer handles it (it saves a
        # checkpoint and closes the workers). A worker dying first would hang the trainer.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    env = TumblerEnv(task=task, randomization=randomization,
                     design=None if design is None else Design.from_sequence(design),
                     **weights.env_kwargs(), **physics.env_kwargs())
    return env if observation == "thesis" else ContextObservation(env, observation)


def build_vec_env(config: TrainConfig, seed: int) -> VecEnv:
    factory: Callable[[], gym.Env[np.ndarray, np.ndarray]] = partial(
        make_env, config.task, config.reward_weights(), config.randomization(), config.profile(),
        config.observation, config.design)
    n = config.envs
    venv: VecEnv = SubprocVecEnv([factory] * n) if n > 1 else DummyVecEnv([factory])
    venv.seed(seed)
    return VecMonitor(venv)


class RunCallback(BaseCallback):
    """Progress bar, episode CSV, and periodic atomic checkpoints."""

    def __init__(self, run_dir: Path, config: TrainConfig, start_steps: int, wall_offset: float = 0.0,
                 stop: StopRequest | None = None) -> None:
        super().__init__()
        self.stop = stop
        self.run_dir = run_dir
        self.config = config
        self.next_checkpoint = (start_steps // config.checkpoint_every + 1) * config.checkpoint_every
        self.recent: deque[float] = deque(maxlen=200)
        self.rollout_final: list[float] = []  # this rollout's final-state R, for TensorBoard
        self.bar = tqdm(total=config.total_steps, initial=start_steps, unit="step", dynamic_ncols=True,
                        desc=f"train {config.task}", mininterval=2.0)
        self.csv_file = (run_dir / "episodes.csv").open("a", newline="")
        self.writer = csv.writer(self.csv_file)
        if self.csv_file.tell() == 0:
            self.writer.writerow(CSV_FIELDS)
        self.start_wall = time.monotonic()
        self.wall_offset = wall_offset  # training seconds before this (resumed) segment
        self.start_steps = start_steps

    def _on_step(self) -> bool:
        steps = self.num_timesteps
        for info in self.locals["infos"]:
            if "final_R" in info:
                self.recent.append(float(info["final_R"]))
                self.rollout_final.append(float(info["final_R"]))
                shaped = float(info["episode"]["r"]) if "episode" in info else float("nan")
                self.writer.writerow((steps, f"{info['final_R']:.5f}", f"{shaped:.5f}",
                                      f"{self.wall_offset + time.monotonic() - self.start_wall:.1f}"))
        self.bar.update(steps - self.bar.n)
        if self.recent:
            rate = (steps - self.start_steps) / max(time.monotonic() - self.start_wall, 1e-9)
            self.bar.set_postfix_str(f"{rate:.0f} steps/s, final R {np.mean(self.recent):+.3f}", refresh=False)
        if steps >= self.next_checkpoint:
            self.save()
            self.next_checkpoint += self.config.checkpoint_every
        return self.stop is None or self.stop.signum is None

    def _on_rollout_end(self) -> None:
        """TensorBoard's ``rollout/final_R_mean``: the final-state R every curve and card reports,
        beside SB3's ``rollout/ep_rew_mean`` (the shaped return training maximises)."""
        if self.rollout_final:
            self.logger.record("rollout/final_R_mean", float(np.mean(self.rollout_final)))
            self.rollout_final.clear()

    def save(self) -> None:
        self.csv_file.flush()
        os.fsync(self.csv_file.fileno())
        save_checkpoint(self.model, self.run_dir)

    def _on_training_end(self) -> None:
        self.csv_file.flush()
        self.bar.close()

    def close(self) -> None:
        self.csv_file.close()
        self.bar.close()


def save_checkpoint(model: BaseAlgorithm, run_dir: Path) -> Path:
    """Write ``checkpoints/step_N.zip`` and atomically replace ``latest.zip``."""
    ckpt_dir = run_dir / "checkpoints"
    ckpt_dir.mkdir(exist_ok=True)
    target = ckpt_dir / f"step_{model.num_timesteps:010d}.zip"
    tmp = run_dir / "latest.tmp.zip"
    model.save(tmp)
    shutil.copyfile(tmp, target)
    with tmp.open("rb") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, run_dir / "latest.zip")
    return target


def _trim_csv(path: Path, max_steps: int) -> float:
    """Drop episodes recorded after the checkpoint we resume from; return the training
    wall time (s) recorded up to it, so the resumed run's clock continues from there."""
    if not path.exists():
        return 0.0
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        return 0.0
    kept = [rows[0]] + [r for r in rows[1:] if r and int(r[0]) <= max_steps]
    tmp = path.with_suffix(".tmp")
    with tmp.open("w", newline="") as fh:
        csv.writer(fh).writerows(kept)
    os.replace(tmp, path)
    return float(kept[-1][3]) if len(kept) > 1 else 0.0


class StopRequest:
    """Ctrl-C and SIGTERM ask training to stop at the next environment step.

    Raising ``KeyboardInterrupt`` from the signal handler could land in the middle of the
    trainer's pipe exchange with its ``SubprocVecEnv`` workers; ``close()`` then waited
    for a reply that had already been read, and the process hung (1 run in 4 in a test).
    So the handler only records the signal; :class:`RunCallback` returns ``False`` on the
    next step and SB3 leaves ``learn()`` cleanly. A second signal stops at once.
    """

    def __init__(self) -> None:
        self.signum: int | None = None

    def __call__(self, signum: int, frame: object) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum


@contextlib.contextmanager
def stop_requests() -> Iterator[StopRequest]:
    """While inside, Ctrl-C and SIGTERM (`kill`, systemd, batch schedulers) only set the
    yielded :class:`StopRequest`; the previous handlers come back on the way out."""
    stop = StopRequest()
    previous_term = signal.signal(signal.SIGTERM, stop)
    previous_int = signal.signal(signal.SIGINT, stop)
    try:
        yield stop
    finally:
        signal.signal(signal.SIGTERM, previous_term)
        signal.signal(signal.SIGINT, previous_int)


def new_model(config: TrainConfig, env: VecEnv, run_dir: Path) -> PPO:
    policy_kwargs: dict[str, Any] = {
        "features_extractor_class": TumblerFeaturesExtractor,
        "net_arch": {"pi": list(config.net_arch), "vf": list(config.net_arch)},
        "activation_fn": torch.nn.Tanh,
    }
    return PPO("MlpPolicy", env, learning_rate=config.learning_rate, n_steps=config.n_steps,
               batch_size=config.batch_size, n_epochs=config.n_epochs, gamma=config.gamma,
               gae_lambda=config.gae_lambda, clip_range=config.clip_range, ent_coef=config.ent_coef,
               vf_coef=config.vf_coef, max_grad_norm=config.max_grad_norm, policy_kwargs=policy_kwargs,
               tensorboard_log=str(run_dir / "tb"), seed=config.seed, device="cpu", verbose=0)


def warm_start(model: PPO, checkpoint: Path, temperature: float = 1.0) -> int:
    """Copy the policy and value weights of ``checkpoint`` into ``model``; returns the
    steps that checkpoint had trained. The networks must have the same shape, which holds
    for any two tasks (they share the observation and action layout) with equal ``net_arch``.
    A ``temperature`` above 1 divides the action logits by it and zeroes the value head
    (:attr:`TrainConfig.warm_start_temperature <tumblebot.training.config.TrainConfig>`)."""
    try:
        source = PPO.load(checkpoint, device="cpu")
    except Exception as exc:  # missing, corrupt, truncated or not SB3 (train() checks existence first)
        raise TrainingError(f"--init-from: {checkpoint} is not a readable PPO checkpoint ({exc})") from None
    try:
        model.policy.load_state_dict(source.policy.state_dict())
    except RuntimeError as exc:
        first = str(exc).splitlines()[0]
        raise TrainingError(f"--init-from: {checkpoint} has other network shapes than this run "
                            f"(net_arch must match): {first}") from None
    if temperature != 1.0:
        with torch.no_grad():
            for parameter in model.policy.action_net.parameters():
                parameter.div_(temperature)
            for parameter in model.policy.value_net.parameters():
                parameter.zero_()
    return int(source.num_timesteps)


def _open_run(config: TrainConfig | None, run_dir: Path, resume: bool, total_steps: int | None
              ) -> tuple[TrainConfig, PPO, VecEnv, int, float]:
    """The run's config, model and environments, and the steps and wall time it starts
    from: read back from ``run_dir`` (``resume``), or new (checked before anything is
    written; a warm start copies ``init_from``'s weights)."""
    config_path = run_dir / "config.json"
    if resume:
        if not (run_dir / "latest.zip").exists():
            raise TrainingError(f"cannot resume: {run_dir / 'latest.zip'} does not exist")
        config = TrainConfig.load(config_path)
        if total_steps is not None:
            config.total_steps = total_steps
            config_path.write_text(config.to_json())
        model = PPO.load(run_dir / "latest.zip", device="cpu")
        start = model.num_timesteps
        wall_offset = _trim_csv(run_dir / "episodes.csv", start)
        env = build_vec_env(config, seed=config.seed + start)
        model.set_env(env)
        model.tensorboard_log = str(run_dir / "tb")
        return config, model, env, start, wall_offset
    if config is None:
        raise TrainingError("a new run needs a training config")
    if (run_dir / "latest.zip").exists():
        raise TrainingError(f"{run_dir} already holds a run; pass --resume to continue it")
    if config.init_from is not None and not Path(config.init_from).is_file():
        raise TrainingError(f"--init-from: {config.init_from} does not exist")
    run_dir.mkdir(parents=True, exist_ok=True)
    env = build_vec_env(config, seed=config.seed)
    model = new_model(config, env, run_dir)
    if config.init_from is not None:
        try:
            config.init_from_steps = warm_start(model, Path(config.init_from), config.warm_start_temperature)
        except TrainingError:
            env.close()
            raise
    config_path.write_text(config.to_json())
    return config, model, env, 0, 0.0


def train(config: TrainConfig | None, run_dir: Path, resume: bool = False, total_steps: int | None = None) -> Path:
    """Train (or resume) a run in ``run_dir``; returns the path of the final checkpoint.

    With ``resume``, the config is read from ``run_dir/config.json`` (``total_steps`` may
    extend it) and training continues from ``latest.zip``. A new run whose config names
    ``init_from`` starts from that checkpoint's weights (a warm start; steps count from 0).
    """
    torch.set_num_threads(1)
    config, model, env, start, wall_offset = _open_run(config, run_dir, resume, total_steps)
    with stop_requests() as stop:
        callback = RunCallback(run_dir, config, start, wall_offset, stop)
        remaining = config.total_steps - start
        try:
            if remaining <= 0:  # a finished run resumed again: nothing to learn, nothing to save
                print(f"{run_dir} already has {start} steps (its total is {config.total_steps}); "
                      "--steps N gives it a larger total")
            else:
                model.learn(total_timesteps=remaining, callback=callback, reset_num_timesteps=False,
                            tb_log_name="ppo")
                if stop.signum is not None:
                    raise KeyboardInterrupt
                callback.save()
        except KeyboardInterrupt:
            callback.save()
            raise TrainingInterrupted(model.num_timesteps, run_dir) from None
        finally:
            callback.close()
            env.close()
    from tumblebot.training.curves import plot_learning_curve

    plot_learning_curve(run_dir / "episodes.csv", run_dir / "learning_curve.png", title=f"{config.task} (PPO)")
    if model.num_timesteps > config.total_steps and remaining > 0:
        rollout = config.n_steps * config.envs
        print(f"stopped at {model.num_timesteps} steps, past the total of {config.total_steps}: PPO collects "
              f"whole rollouts of {rollout} steps ({config.n_steps} per environment x {config.envs})")
    return run_dir / "latest.zip"
