"""Imitation of the ``goto`` controller (behaviour cloning with DAgger): PPO's warm start.

PPO from random weights needs millions of steps to find the "turn, drive, stop" pattern
that :mod:`tumblebot.sim.goto` writes down in a page. So a navigation policy first learns
to do what ``goto`` would, then PPO (``tumblebot train --init-from``) improves on it.

DAgger (Ross et al., 2011): iteration 0 lets ``goto`` drive and records, for every state,
its action; every later iteration lets the student drive (its deterministic action) and
records what ``goto`` would have done in the states the student reaches (``goto`` is told
the action actually taken, so its estimates follow what happened). The student is trained
by cross-entropy on everything recorded so far, so it learns to recover from its own
mistakes. Its value network is fitted to the discounted shaped returns of the episodes
(the student's own from iteration 1 on), so PPO's first advantages are not noise.

The run folder is a training run like any other (``config.json``, ``latest.zip``,
``episodes.csv``), so ``tumblebot export`` and ``tumblebot train --init-from`` take it;
``imitation.csv`` holds one row per iteration, ``dagger.npz`` the aggregated data.
"""

from __future__ import annotations

import csv
import json
import signal
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from tumblebot.sim.goto import GotoConfig, GotoController
from tumblebot.training.config import TrainConfig, TrainingError
from tumblebot.training.ppo import (
    CSV_FIELDS,
    StopRequest,
    TrainingInterrupted,
    build_vec_env,
    new_model,
    save_checkpoint,
)

IMITATION_FIELDS = ("iteration", "driver", "episodes", "dataset", "agreement", "student_final_R", "teacher_final_R",
                    "cross_entropy", "wall_seconds")


@dataclass(frozen=True)
class ImitationConfig:
    """DAgger settings (recorded in ``imitation.json``)."""

    iterations: int = 6  #: iteration 0 is the teacher's; the rest the student's
    episodes: int = 400  #: episodes collected per iteration
    updates: int = 4000  #: gradient steps on the aggregated data after each iteration
    batch_size: int = 512
    learning_rate: float = 1e-3

    def __post_init__(self) -> None:
        for name in ("iterations", "episodes", "updates", "batch_size"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise TrainingError(f"imitation {name}={getattr(self, name)!r} must be a positive integer")
        if not self.learning_rate > 0:
            raise TrainingError(f"imitation learning_rate={self.learning_rate!r} must be positive")


@dataclass
class Batch:
    inputs: np.ndarray  #: (N, 23) policy inputs
    labels: np.ndarray  #: (N, 2) the teacher's actions
    returns: np.ndarray  #: (N,) discounted shaped return from that state on
    student_agreement: float  #: fraction of student-driven states where the student chose the label
    final_R: list[float]
    shaped_return: list[float]  #: each episode's undiscounted sum of shaped rewards


def collect(model: object, venv: object, episodes: int, student_drives: bool, gamma: float,
            episode_steps: int, stop: StopRequest, bar: tqdm[Any]) -> Batch:
    """Run ``episodes`` episodes in ``venv``, driven by the teacher or by ``model``'s
    deterministic policy, labelling every state with the teacher's action."""
    n = venv.num_envs  # type: ignore[attr-defined]
    teachers = [GotoController(GotoConfig(episode_steps=episode_steps)) for _ in range(n)]
    obs = venv.reset()  # type: ignore[attr-defined]
    step = np.zeros(n, dtype=int)
    trace: list[list[tuple[np.ndarray, tuple[int, int], float]]] = [[] for _ in range(n)]
    inputs: list[np.ndarray] = []
    labels: list[tuple[int, int]] = []
    returns: list[float] = []
    final: list[float] = []
    shaped: list[float] = []
    agree = total = 0
    while len(final) < episodes:
        if stop.signum is not None:
            raise KeyboardInterrupt
        label = [teachers[i].act(obs[i, :9], int(step[i])) for i in range(n)]
        if student_drives:
            actions = np.asarray(model.predict(obs, deterministic=True)[0])  # type: ignore[attr-defined]
            agree += int(sum(tuple(int(v) for v in actions[i]) == label[i] for i in range(n)))
            total += n
            for i in range(n):
                teachers[i].taken((int(actions[i][0]), int(actions[i][1])))
        else:
            actions = np.asarray(label)
        new_obs, rewards, dones, infos = venv.step(actions)  # type: ignore[attr-defined]
        for i in range(n):
            trace[i].append((obs[i].copy(), label[i], float(rewards[i])))
            step[i] += 1
            if dones[i]:
                g = 0.0
                for x, a, r in reversed(trace[i]):
                    g = r + gamma * g
                    inputs.append(x)
                    labels.append(a)
                    returns.append(g)
                final.append(float(infos[i]["final_R"]))
                shaped.append(sum(r for _, _, r in trace[i]))
                trace[i], step[i] = [], 0
                teachers[i].reset()
                bar.update(1)
        obs = new_obs
    return Batch(np.asarray(inputs, dtype=np.float32), np.asarray(labels, dtype=np.int64),
                 np.asarray(returns, dtype=np.float32), agree / total if total else float("nan"), final, shaped)


def fit(model: object, optimiser: torch.optim.Optimizer, inputs: np.ndarray, labels: np.ndarray,
        returns: np.ndarray, config: ImitationConfig, seed: int, stop: StopRequest) -> float:
    """Cross-entropy on the labels plus squared error on the returns, ``updates`` steps of
    minibatches drawn with replacement; returns the last 200 steps' mean cross-entropy."""
    policy = model.policy  # type: ignore[attr-defined]
    x, a, g = torch.as_tensor(inputs), torch.as_tensor(labels), torch.as_tensor(returns)
    rng = np.random.default_rng(seed)
    policy.set_training_mode(True)
    recent: list[float] = []
    for _ in range(config.updates):
        if stop.signum is not None:
            raise KeyboardInterrupt
        idx = torch.as_tensor(rng.integers(0, len(x), config.batch_size))
        values, log_prob, _ = policy.evaluate_actions(x[idx], a[idx])
        cross_entropy = -log_prob.mean()
        loss = cross_entropy + 0.5 * torch.nn.functional.mse_loss(values.flatten(), g[idx])
        optimiser.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
        optimiser.step()
        recent = [*recent[-199:], float(cross_entropy.detach())]
    policy.set_training_mode(False)
    return float(np.mean(recent))


def imitate(config: TrainConfig, imitation: ImitationConfig, run_dir: Path) -> Path:
    """DAgger of ``goto`` into a new run in ``run_dir``; returns its checkpoint."""
    if config.observation != "context":
        raise TrainingError("imitation needs the context observation (goto uses memory the thesis's 9 numbers lack)")
    from tumblebot.sim.goto import check_navigation_task

    check_navigation_task(config.task)
    if (run_dir / "latest.zip").exists():
        raise TrainingError(f"{run_dir} already holds a run")
    torch.set_num_threads(1)
    torch.manual_seed(config.seed)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(config.to_json())  # rewritten with the steps taken at the end
    (run_dir / "imitation.json").write_text(json.dumps(asdict(imitation), indent=2) + "\n")
    env = build_vec_env(config, seed=config.seed)
    model = new_model(config, env, run_dir)
    optimiser = torch.optim.Adam(model.policy.parameters(), lr=imitation.learning_rate)
    stop = StopRequest()
    previous = signal.signal(signal.SIGINT, stop), signal.signal(signal.SIGTERM, stop)
    start = time.monotonic()
    steps = 0
    data: list[Batch] = []
    episode_steps = 20
    try:
        with (run_dir / "imitation.csv").open("w", newline="") as log, \
                (run_dir / "episodes.csv").open("w", newline="") as episodes_log:
            writer, episodes_writer = csv.writer(log), csv.writer(episodes_log)
            writer.writerow(IMITATION_FIELDS)
            episodes_writer.writerow(CSV_FIELDS)
            for iteration in range(imitation.iterations):
                student = iteration > 0
                with tqdm(total=imitation.episodes, unit="ep", dynamic_ncols=True, mininterval=2.0,
                          desc=f"DAgger {iteration}/{imitation.iterations - 1} ({'student' if student else 'goto'})"
                          ) as bar:
                    batch = collect(model, env, imitation.episodes, student, config.gamma, episode_steps, stop, bar)
                data.append(batch)
                steps += len(batch.labels)
                inputs = np.concatenate([b.inputs for b in data])
                labels = np.concatenate([b.labels for b in data])
                returns = np.concatenate([b.returns for b in data])
                np.savez_compressed(run_dir / "dagger.npz", inputs=inputs, labels=labels, returns=returns)
                loss = fit(model, optimiser, inputs, labels, returns, imitation, config.seed + iteration, stop)
                wall = time.monotonic() - start
                mean_r = float(np.mean(batch.final_R))
                writer.writerow((iteration, "student" if student else "goto", len(batch.final_R),
                                 sum(len(b.labels) for b in data), f"{batch.student_agreement:.4f}",
                                 f"{mean_r:.4f}" if student else "", "" if student else f"{mean_r:.4f}",
                                 f"{loss:.4f}", f"{wall:.1f}"))
                log.flush()
                for r, g in zip(batch.final_R, batch.shaped_return, strict=True):
                    episodes_writer.writerow((steps, f"{r:.5f}", f"{g:.5f}", f"{wall:.1f}"))
                episodes_log.flush()
                model.num_timesteps = steps
                save_checkpoint(model, run_dir)
                print(f"DAgger {iteration}: {'student' if student else 'goto'} mean final R {mean_r:.3f}"
                      + (f", agreement with goto {batch.student_agreement:.3f}" if student else "")
                      + f"; cross-entropy after fitting {loss:.3f}", flush=True)
    except KeyboardInterrupt:
        raise TrainingInterrupted(steps, run_dir) from None
    finally:
        signal.signal(signal.SIGINT, previous[0])
        signal.signal(signal.SIGTERM, previous[1])
        env.close()
    config.total_steps = max(steps, 1)
    (run_dir / "config.json").write_text(config.to_json())
    return run_dir / "latest.zip"
