"""Imitation of the ``goto`` controller (behaviour cloning with DAgger): PPO's warm start.

PPO from random weights needs millions of steps to find the "turn, drive, stop" pattern
that :mod:`tumblebot.sim.control.goto` writes down in a page. So a navigation policy first learns
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
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from tumblebot.sim.control.goto import GotoConfig, GotoController
from tumblebot.sim.observation import CHOICE_LAYOUTS, EPISODE_STEPS, fields_slice, teacher_name
from tumblebot.training.config import TrainConfig, TrainingError
from tumblebot.training.ppo import (
    CSV_FIELDS,
    StopRequest,
    TrainingInterrupted,
    build_vec_env,
    new_model,
    save_checkpoint,
    stop_requests,
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
    #: the step size each fit ends at, falling linearly from ``learning_rate`` over its
    #: updates (None: constant, as every run before it): a smaller last step fits the rare
    #: states where a body's settings disagree, which a constant 1e-3 leaves a few % wrong
    learning_rate_end: float | None = None

    def __post_init__(self) -> None:
        for name in ("iterations", "episodes", "updates", "batch_size"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise TrainingError(f"imitation {name}={getattr(self, name)!r} must be a positive integer")
        if not self.learning_rate > 0:
            raise TrainingError(f"imitation learning_rate={self.learning_rate!r} must be positive")
        if self.learning_rate_end is not None and not 0 < self.learning_rate_end <= self.learning_rate:
            raise TrainingError(f"imitation learning_rate_end={self.learning_rate_end!r} must be positive and at most "
                                f"learning_rate={self.learning_rate!r}")


@dataclass
class Batch:
    inputs: np.ndarray  #: (N, 23) policy inputs
    labels: np.ndarray  #: (N, 2) the teacher's actions
    returns: np.ndarray  #: (N,) discounted shaped return from that state on
    student_agreement: float  #: fraction of student-driven states where the student chose the label
    final_R: list[float]
    shaped_return: list[float]  #: each episode's undiscounted sum of shaped rewards


Teacher = Callable[[np.ndarray], GotoConfig]  #: a design (x, y, z, l) → the goto settings that label its episode


def goto_teacher(episode_steps: int = EPISODE_STEPS) -> Teacher:
    """goto with its defaults on every body."""
    return lambda design: GotoConfig(episode_steps=episode_steps)


def choice_teacher(choice: Any, episode_steps: int = EPISODE_STEPS) -> Teacher:
    """goto with the settings a :class:`~tumblebot.training.choice.GotoChoice` predicts
    best for the body (of its layout's: ``RESIDUAL_GOTO`` or ``DUAL_GOTO`` for
    ``dual``, ``PLAN_GOTO`` or ``PLAN_DUAL_GOTO`` for ``dual-plan``, and ``PLAN_SHORT_GOTO``
    too for ``tri-plan``)."""

    def settings(design: np.ndarray) -> GotoConfig:
        return GotoConfig(episode_steps=episode_steps, **choice.chosen(design))

    return settings


def collect(model: object, venv: object, episodes: int, student_drives: bool, gamma: float,
            episode_steps: int, stop: StopRequest, bar: tqdm[Any], teacher: Teacher | None = None) -> Batch:
    """Run ``episodes`` episodes in ``venv``, driven by the teacher or by ``model``'s
    deterministic policy, labelling every state with the teacher's action. The teacher
    of an episode is goto with the settings ``teacher`` gives for its design (read from
    the observation's design fields; default: goto's defaults everywhere)."""
    n = venv.num_envs  # type: ignore[attr-defined]
    teacher = teacher or goto_teacher(episode_steps)
    design = fields_slice("context", "design_x", "design_l")  # the same in every design-conditioned layout
    thesis = fields_slice("context", "px", "cmd_left")
    obs = venv.reset()  # type: ignore[attr-defined]
    teachers = [GotoController(teacher(obs[i, design])) for i in range(n)]
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
        label = [teachers[i].act(obs[i, thesis], int(step[i])) for i in range(n)]
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
                teachers[i] = GotoController(teacher(new_obs[i, design]))  # the next episode's body
                bar.update(1)
        obs = new_obs
    return Batch(np.asarray(inputs, dtype=np.float32), np.asarray(labels, dtype=np.int64),
                 np.asarray(returns, dtype=np.float32), agree / total if total else float("nan"), final, shaped)


SEARCH_TARGETS = ("best", "expected")
#: ``expected`` target: the mean-score advantage is multiplied by ``ADVANTAGE_SCALE`` and
#: cross-entropy toward goto's own action added with weight ``GOTO_WEIGHT``. Between goto's
#: action and one ``Δ`` better, the loss is least where the other has probability
#: ``1 − GOTO_WEIGHT / (ADVANTAGE_SCALE · Δ)``: the student leaves goto's action where
#: another scores better on average by more than ``2 · GOTO_WEIGHT / ADVANTAGE_SCALE``,
#: a hundredth of R.
ADVANTAGE_SCALE = 10.0
GOTO_WEIGHT = 0.05


@dataclass
class Labelled:
    """Labelled states of one iteration (or the run a refine starts from)."""

    inputs: np.ndarray  #: (N, size) policy inputs
    labels: np.ndarray  #: (N, 2) the teacher's action: goto's, or the search's best
    returns: np.ndarray  #: (N,) discounted shaped return from that state on
    goto_labels: np.ndarray  #: (N, 2) goto's own action
    values: np.ndarray  #: (N, 9) each action's mean score where searched, else NaN

    @classmethod
    def of_goto(cls, inputs: np.ndarray, labels: np.ndarray, returns: np.ndarray) -> Labelled:
        return cls(inputs, labels, returns, labels, np.full((len(labels), 9), np.nan, dtype=np.float32))

    @classmethod
    def concatenate(cls, parts: list[Labelled]) -> Labelled:
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                     ("inputs", "labels", "returns", "goto_labels", "values")))


def joint_log_probs(distribution: Any) -> torch.Tensor:
    """``(B, 9)`` log-probabilities of the joint actions (right, left) in
    :data:`tumblebot.training.lookahead.ALL_ACTIONS` order, from SB3's per-motor distribution."""
    right, left = (d.logits for d in distribution.distribution)
    joint: torch.Tensor = (right[:, :, None] + left[:, None, :]).reshape(-1, 9)
    return joint


def fit(model: object, optimiser: torch.optim.Optimizer, data: Labelled, config: ImitationConfig, seed: int,
        stop: StopRequest, target: str = "best") -> float:
    """``updates`` steps of minibatches drawn with replacement, each minimising the action
    loss plus squared error on the returns; returns the last 200 steps' mean action loss.

    The action loss is cross-entropy toward ``labels``, except on searched states with
    ``target="expected"``: there it is minus the expected advantage of the student's action
    distribution (each action's mean score less their mean, times :data:`ADVANTAGE_SCALE`)
    plus cross-entropy toward goto's own action, weighted by :data:`GOTO_WEIGHT`."""
    if target not in SEARCH_TARGETS:
        raise TrainingError(f"search target {target!r} must be one of: {', '.join(SEARCH_TARGETS)}")
    policy = model.policy  # type: ignore[attr-defined]
    x, a, g = torch.as_tensor(data.inputs), torch.as_tensor(data.labels), torch.as_tensor(data.returns)
    own = torch.as_tensor(data.goto_labels)
    searched = torch.as_tensor(np.isfinite(data.values[:, 0]) & (target == "expected"))
    values = torch.as_tensor(np.nan_to_num(data.values, nan=0.0))
    advantage = torch.where(searched[:, None], ADVANTAGE_SCALE * (values - values.mean(dim=1, keepdim=True)), 0.0)
    rng = np.random.default_rng(seed)
    policy.set_training_mode(True)
    recent: list[float] = []
    for update in range(config.updates):
        if stop.signum is not None:
            raise KeyboardInterrupt
        if config.learning_rate_end is not None:
            fraction = update / max(config.updates - 1, 1)
            for group in optimiser.param_groups:
                group["lr"] = config.learning_rate + fraction * (config.learning_rate_end - config.learning_rate)
        idx = torch.as_tensor(rng.integers(0, len(x), config.batch_size))
        in_search = searched[idx]
        chosen = torch.where(in_search[:, None], own[idx], a[idx])  # goto's own action in the search
        distribution = policy.get_distribution(x[idx])
        expected = (torch.exp(joint_log_probs(distribution)) * advantage[idx]).sum(dim=1)  # 0 outside it
        action_loss = -distribution.log_prob(chosen) * torch.where(in_search, GOTO_WEIGHT, 1.0) - expected
        state_values = policy.predict_values(x[idx])
        loss = action_loss.mean() + 0.5 * torch.nn.functional.mse_loss(state_values.flatten(), g[idx])
        optimiser.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
        optimiser.step()
        recent = [*recent[-199:], float(action_loss.mean().detach())]
    policy.set_training_mode(False)
    return float(np.mean(recent))


@dataclass(frozen=True)
class IterationSummary:
    """One DAgger iteration, as ``imitation.csv`` records it."""

    iteration: int
    driver: str  #: the teacher's name ("goto" or "plan") or "student"
    episodes: int
    dataset: int  #: labelled states aggregated so far
    agreement: float  #: the student's agreement with its teacher where it drove (NaN for the teacher)
    mean_final_R: float  #: of this iteration's episodes, under its driver
    cross_entropy: float  #: after fitting
    wall_seconds: float
    teacher: str = "goto"  #: the hand-written controller imitated

    def row(self) -> tuple[object, ...]:
        student = self.driver == "student"
        mean = f"{self.mean_final_R:.4f}"
        return (self.iteration, self.driver, self.episodes, self.dataset, f"{self.agreement:.4f}",
                mean if student else "", "" if student else mean, f"{self.cross_entropy:.4f}",
                f"{self.wall_seconds:.1f}")

    def describe(self) -> str:
        agreement = f", agreement with {self.teacher} {self.agreement:.3f}" if self.driver == "student" else ""
        return (f"DAgger {self.iteration}: {self.driver} mean final R {self.mean_final_R:.3f}{agreement}; "
                f"cross-entropy after fitting {self.cross_entropy:.3f}")


class _RunLogs:
    """``imitation.csv`` (one row per iteration) and ``episodes.csv`` (one per episode,
    the columns of a PPO run's, so learning curves read both)."""

    def __init__(self, run_dir: Path) -> None:
        self.log = (run_dir / "imitation.csv").open("w", newline="")
        self.episodes = (run_dir / "episodes.csv").open("w", newline="")
        self.writer, self.episodes_writer = csv.writer(self.log), csv.writer(self.episodes)
        self.writer.writerow(IMITATION_FIELDS)
        self.episodes_writer.writerow(CSV_FIELDS)

    def record(self, summary: IterationSummary, batch: Batch, steps: int) -> None:
        self.writer.writerow(summary.row())
        self.log.flush()
        for r, g in zip(batch.final_R, batch.shaped_return, strict=True):
            self.episodes_writer.writerow((steps, f"{r:.5f}", f"{g:.5f}", f"{summary.wall_seconds:.1f}"))
        self.episodes.flush()

    def close(self) -> None:
        self.log.close()
        self.episodes.close()


def _new_run(config: TrainConfig, imitation: ImitationConfig, run_dir: Path,
             teacher: dict[str, Any] | None = None) -> None:
    """Check the run can start, then write its config (rewritten with the steps taken at
    the end) and ``imitation.json``: the DAgger settings and the teacher."""
    if config.observation == "thesis":
        raise TrainingError("imitation needs a design-conditioned observation (context, memory, residual, dual, "
                            "dual-plan or tri-plan; goto uses memory the thesis's 9 numbers lack)")
    from tumblebot.sim.control.goto import check_navigation_task

    check_navigation_task(config.task)
    if (run_dir / "latest.zip").exists():
        raise TrainingError(f"{run_dir} already holds a run")
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(config.to_json())
    record = {**asdict(imitation), "teacher": teacher or {"kind": "goto"}}
    (run_dir / "imitation.json").write_text(json.dumps(record, indent=2) + "\n")


def _fit_and_save(model: Any, optimiser: torch.optim.Optimizer, parts: list[Labelled], imitation: ImitationConfig,
                  seed: int, stop: StopRequest, run_dir: Path, target: str = "best") -> tuple[int, float]:
    """Aggregate ``parts`` (one per iteration), save them as ``dagger.npz``, fit the
    student to them; returns the dataset size and the action loss."""
    data = Labelled.concatenate(parts)
    np.savez_compressed(run_dir / "dagger.npz", inputs=data.inputs, labels=data.labels, returns=data.returns,
                        goto_labels=data.goto_labels, values=data.values)
    return len(data.labels), fit(model, optimiser, data, imitation, seed, stop, target)


def _end_iteration(model: Any, run_dir: Path, logs: _RunLogs, summary: IterationSummary, batch: Batch, steps: int,
                   on_iteration: Callable[[IterationSummary], None] | None) -> None:
    """Log the iteration, checkpoint the student, tell the caller."""
    logs.record(summary, batch, steps)
    model.num_timesteps = steps
    save_checkpoint(model, run_dir)
    if on_iteration is not None:
        on_iteration(summary)


def _finish_run(config: TrainConfig, run_dir: Path, steps: int) -> Path:
    """Rewrite the run's config with the steps taken; the run's checkpoint."""
    config.total_steps = max(steps, 1)
    (run_dir / "config.json").write_text(config.to_json())
    return run_dir / "latest.zip"


def imitate(config: TrainConfig, imitation: ImitationConfig, run_dir: Path,
            on_iteration: Callable[[IterationSummary], None] | None = None, choice: Path | None = None) -> Path:
    """DAgger of ``goto`` into a new run in ``run_dir``; returns its checkpoint.
    ``on_iteration`` sees each iteration's summary (the CLI prints it). A ``dual`` student
    needs ``choice``, a :class:`~tumblebot.training.choice.GotoChoice` file: its teacher is
    goto with the settings that file predicts better for each body (copied into the run)."""
    teacher, record = goto_teacher(), None
    name = teacher_name(config.observation)
    dual = config.observation in CHOICE_LAYOUTS
    if dual != (choice is not None):
        raise TrainingError(f"a {', '.join(CHOICE_LAYOUTS)} student needs --choice (which goto settings suit which "
                            "body), and only such a student takes it")
    if choice is not None:
        from tumblebot.sim.control.policy import sha256_of
        from tumblebot.training.choice import GotoChoice

        model_of_choice = GotoChoice.load(choice)  # checked before the run folder is written
        if model_of_choice.layout != config.observation:
            raise TrainingError(f"--choice {choice} was fitted for the {model_of_choice.layout} layout's gotos, not "
                                f"{config.observation}'s (tumblebot choice sweep --layout {config.observation})")
        teacher = choice_teacher(model_of_choice)
        record = {"kind": "goto-choice", "choice": "choice.json", "choice_sha256": sha256_of(choice)}
    _new_run(config, imitation, run_dir, record)
    if choice is not None:
        (run_dir / "choice.json").write_bytes(choice.read_bytes())
    torch.set_num_threads(1)
    torch.manual_seed(config.seed)
    env = build_vec_env(config, seed=config.seed)
    model = new_model(config, env, run_dir)
    optimiser = torch.optim.Adam(model.policy.parameters(), lr=imitation.learning_rate)
    start, steps = time.monotonic(), 0
    data: list[Labelled] = []
    logs = _RunLogs(run_dir)
    with stop_requests() as stop:
        try:
            for iteration in range(imitation.iterations):
                driver = "student" if iteration > 0 else name
                with tqdm(total=imitation.episodes, unit="ep", dynamic_ncols=True, mininterval=2.0,
                          desc=f"DAgger {iteration}/{imitation.iterations - 1} ({driver})") as bar:
                    batch = collect(model, env, imitation.episodes, iteration > 0, config.gamma, EPISODE_STEPS,
                                    stop, bar, teacher)
                data.append(Labelled.of_goto(batch.inputs, batch.labels, batch.returns))
                steps += len(batch.labels)
                dataset, loss = _fit_and_save(model, optimiser, data, imitation, config.seed + iteration, stop,
                                              run_dir)
                summary = IterationSummary(iteration, driver, len(batch.final_R), dataset, batch.student_agreement,
                                           float(np.mean(batch.final_R)), loss, time.monotonic() - start, name)
                _end_iteration(model, run_dir, logs, summary, batch, steps, on_iteration)
        except KeyboardInterrupt:
            raise TrainingInterrupted(steps, run_dir) from None
        finally:
            logs.close()
            env.close()
    return _finish_run(config, run_dir, steps)


def _discounted(rewards: np.ndarray, gamma: float) -> np.ndarray:
    """The discounted return from every step of an episode on."""
    out, g = np.empty(len(rewards), dtype=np.float32), 0.0
    for k in range(len(rewards) - 1, -1, -1):
        g = float(rewards[k]) + gamma * g
        out[k] = g
    return out


def _lookahead_episodes(spec: Any, student: Path, seed: int, iteration: int, imitation: ImitationConfig,
                        workers: int, stop: StopRequest) -> list[Any]:
    """One refine iteration's episodes (their seeds drawn from ``seed`` and ``iteration``)."""
    from tumblebot.training.lookahead import run_episodes

    seeds = [int(np.random.SeedSequence([seed, 7919, iteration, i]).generate_state(1)[0])
             for i in range(imitation.episodes)]
    records = []
    with tqdm(total=len(seeds), unit="ep", dynamic_ncols=True, mininterval=2.0,
              desc=f"DAgger+lookahead {iteration}/{imitation.iterations - 1}") as bar:
        for record in run_episodes(spec, student, seeds, workers, lambda: stop.signum is not None):
            records.append(record)
            bar.update(1)
    if stop.signum is not None:
        raise KeyboardInterrupt
    return records


def _summarise(records: list[Any], iteration: int, dataset: int, loss: float, wall: float
               ) -> tuple[IterationSummary, Batch]:
    """A refine iteration's summary, and its episodes as a :class:`Batch` for the logs."""
    agreement = sum(r.agreed for r in records) / max(sum(len(r.labels) for r in records), 1)
    final = [r.final_R for r in records]
    empty = np.zeros((0,), dtype=np.float32)
    batch = Batch(empty, empty, empty, agreement, final, [float(np.sum(r.rewards)) for r in records])
    return IterationSummary(iteration, "student", len(records), dataset, agreement, float(np.mean(final)), loss,
                            wall), batch


def refine(source: Path, run_dir: Path, imitation: ImitationConfig, horizon: int, workers: int,
           on_iteration: Callable[[IterationSummary], None] | None = None, draws: int = 0,
           target: str = "best") -> Path:
    """DAgger toward ``goto`` with a search over the last ``horizon`` steps
    (:mod:`tumblebot.training.lookahead`; clairvoyant with ``draws = 0``, else each action
    scored over ``draws`` futures drawn anew), from the imitation run ``source``: its weights,
    and its goto-labelled states before that window (the teacher is goto there too). The
    student learns the search's best action (``target="best"``) or the action with the best
    mean score in states it cannot tell apart (``"expected"``, :func:`fit`). The student
    drives every iteration; returns the new run's checkpoint."""
    from stable_baselines3 import PPO

    from tumblebot.sim.control.policy import LAYOUTS
    from tumblebot.training.export import export_onnx, write_card
    from tumblebot.training.lookahead import WorkerSpec

    config = TrainConfig.load(source / "config.json")
    if target not in SEARCH_TARGETS:
        raise TrainingError(f"search target {target!r} must be one of: {', '.join(SEARCH_TARGETS)}")
    if not 1 <= horizon <= EPISODE_STEPS:
        raise TrainingError(f"--lookahead {horizon} must be 1–{EPISODE_STEPS} steps")
    if not (source / "dagger.npz").is_file():
        raise TrainingError(f"{source} has no dagger.npz: refine starts from a tumblebot imitate run")
    if config.observation in CHOICE_LAYOUTS:
        raise TrainingError(f"{source} is a {config.observation} run: refine's search continues with goto's "
                            "defaults, not the setting its teacher chose for each body")
    config.init_from, config.init_from_steps = str(source / "latest.zip"), config.total_steps
    _new_run(config, imitation, run_dir, {"kind": "goto+search", "lookahead": horizon, "draws": draws,
                                          "future": "drawn anew" if draws else "the episode's own (clairvoyant)",
                                          "target": target})
    torch.set_num_threads(1)
    model = PPO.load(source / "latest.zip", device="cpu")
    old = np.load(source / "dagger.npz")
    before = old["inputs"][:, LAYOUTS["context"].index("steps_left")] > horizon / EPISODE_STEPS + 1e-6
    data = [Labelled.of_goto(old["inputs"][before], old["labels"][before], old["returns"][before])]
    spec = WorkerSpec(config.task, config.tumbling_designs_only, config.profile(), config.reward_weights(),
                      horizon, draws)
    optimiser = torch.optim.Adam(model.policy.parameters(), lr=imitation.learning_rate)
    start, steps = time.monotonic(), 0
    logs = _RunLogs(run_dir)
    with stop_requests() as stop:
        try:
            for iteration in range(imitation.iterations):
                student = run_dir / "student.onnx"
                export_onnx(model, student)
                write_card(student, config.task, steps, config)
                records = _lookahead_episodes(spec, student, config.seed, iteration, imitation, workers, stop)
                returns = [_discounted(record.rewards, config.gamma) for record in records]
                data.append(Labelled(*(np.concatenate(parts) for parts in (
                    [r.inputs for r in records], [r.labels for r in records], returns,
                    [r.goto_labels for r in records], [r.values for r in records]))))
                steps += sum(len(r.labels) for r in records)
                dataset, loss = _fit_and_save(model, optimiser, data, imitation, config.seed + iteration, stop,
                                              run_dir, target)
                summary, batch = _summarise(records, iteration, dataset, loss, time.monotonic() - start)
                _end_iteration(model, run_dir, logs, summary, batch, steps, on_iteration)
        except KeyboardInterrupt:
            raise TrainingInterrupted(steps, run_dir) from None
        finally:
            logs.close()
    return _finish_run(config, run_dir, steps)
