"""A privileged teacher for imitation: ``goto``, with a clairvoyant search over its last steps.

``goto`` stops within half a step of the goal and never uses the four actions that hold
one leg; on the thesis's ξ = 3 robot that leaves it about 0.12 short of a perfect final
R. In the last ``horizon`` steps of an episode this teacher tries every one of the nine
actions from a snapshot of the simulation (:meth:`TumblerEnv.snapshot`), follows each
with ``goto`` to the end, and labels the state with the action whose episode ended best.
With ``draws = 0`` the snapshot's own motor noise and latency still to come are used, so
the teacher sees a future no policy can see ("learning by cheating"); with ``draws = K``
each action is scored by the mean final R over ``K`` futures drawn anew
(:meth:`TumblerEnv.reseed_motor_noise`; the same ``K`` for every action), so the teacher
no longer sees the noise to come, only the hidden state (leg angles, masses, friction).
Earlier steps are labelled by ``goto`` itself.

The search also records every action's score (:attr:`EpisodeRecord.values`). A student that
copies the best action (target ``best``) learns the action that is *most often* best in
states that look alike to it, which need not be the one best *on average* when the best
action depends on what it cannot see (leg angles); on the thesis's ξ = 3 robot that
student fell 0.05 below goto. Target ``expected`` (:func:`tumblebot.training.imitation.fit`)
instead maximises each action's mean score under the student's own action distribution,
so over states it cannot tell apart it picks the action with the best mean score.

Episodes run in worker processes (each with its own environment, the student as an ONNX
file exported by the caller, and the teacher), since the search needs an environment of
its own that a vectorised one cannot lend.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.control.goto import GotoController
from tumblebot.sim.evaluation.pool import WorkerPool
from tumblebot.sim.evaluation.rollout import GotoActor, branch, run_episode
from tumblebot.sim.world.physics import PhysicsProfile
from tumblebot.training.config import RewardWeights

ALL_ACTIONS: tuple[tuple[int, int], ...] = tuple((r, left) for r in range(3) for left in range(3))
_UNSEARCHED = np.full(len(ALL_ACTIONS), np.nan)  #: the scores of a step goto labels (copied into the record)


@dataclass(frozen=True)
class EpisodeRecord:
    """One episode: the student's inputs, the teacher's labels, the shaped rewards."""

    inputs: np.ndarray
    labels: np.ndarray
    goto_labels: np.ndarray  #: goto's own action at every step (the label outside the search)
    values: np.ndarray  #: (steps, 9) each action's mean final R in :data:`ALL_ACTIONS` order; NaN unsearched
    rewards: np.ndarray
    final_R: float
    agreed: int  #: steps where the student's action was the label
    searched: int  #: steps labelled by the search (the rest by goto)


@dataclass(frozen=True)
class WorkerSpec:
    """What a worker needs to build its environment, student and teacher (picklable)."""

    task: str
    tumbling_designs_only: bool
    physics: PhysicsProfile
    weights: RewardWeights  #: the environment's reward shaping (the training config's)
    horizon: int  #: the last steps labelled by the search
    draws: int = 0  #: futures drawn anew per action (0: the episode's own, clairvoyant)


@dataclass
class _Worker:
    """A worker's state: its environment, the student (if any) and what to do."""

    env: Any
    student: Any
    spec: WorkerSpec

    def close(self) -> None:
        self.env.close()


def _worker(spec: WorkerSpec, student: str | None) -> _Worker:
    from tumblebot.sim.control.policy import OnnxPolicy
    from tumblebot.sim.world.env import TumblerEnv
    from tumblebot.sim.world.randomization import Randomization

    env = TumblerEnv(task=spec.task, randomization=spec.physics.randomization(Randomization(
        tumbling_designs_only=spec.tumbling_designs_only)), **spec.weights.env_kwargs(),
        **spec.physics.env_kwargs())
    return _Worker(env, OnnxPolicy(Path(student)) if student else None, spec)


def _search(env: Any, goto: GotoController, obs: np.ndarray, step: int, draws: int = 0,
            seed: int = 0) -> tuple[int, int]:
    """The action whose episode, continued by ``goto``, ends with the best final R: in
    the episode's own future (``draws = 0``), or on average over ``draws`` futures drawn
    from ``seed`` and ``step``."""
    return search_values(env, goto, obs, step, draws, seed)[0]


def search_values(env: Any, goto: GotoController, obs: np.ndarray, step: int, draws: int = 0,
                  seed: int = 0) -> tuple[tuple[int, int], np.ndarray]:
    """:func:`_search`'s action, and every action's mean final R (:data:`ALL_ACTIONS` order)."""
    snap = env.snapshot()
    values = np.empty(len(ALL_ACTIONS))
    try:
        futures = max(draws, 1)
        for k, action in enumerate(ALL_ACTIONS):
            total = 0.0
            for draw in range(futures):
                follower = copy.deepcopy(goto)  # goto's memory before the step, told the action taken
                follower.act(obs, step)
                follower.taken(action)
                reseed = partial(env.reseed_motor_noise, [seed, step, draw]) if draws else None
                total += float(branch(env, snap, action, GotoActor(follower), step, reseed)["final_R"])
            values[k] = total / futures
        env.restore(snap)
    finally:
        env.release(snap)
    return ALL_ACTIONS[int(np.argmax(values))], values  # the first of equals, as before


class _Teacher:
    """Drives an episode with the student (or, without one, the teacher's labels) and
    records the student's inputs and the teacher's labels at every step: ``goto``'s
    action, or in the last ``horizon`` steps the clairvoyant search's."""

    def __init__(self, worker: _Worker, seed: int) -> None:
        self.env, self.student, self.spec, self.seed = worker.env, worker.student, worker.spec, seed
        self.goto = GotoController()
        self.inputs: list[np.ndarray] = []
        self.labels: list[tuple[int, int]] = []
        self.goto_labels: list[tuple[int, int]] = []
        self.values: list[np.ndarray] = []
        self.agreed = self.searched = 0

    def reset(self, seed: int, design: tuple[float, float, float, float]) -> None:
        self.goto.reset()
        if self.student is not None:
            self.student.reset(design)

    def act(self, obs: np.ndarray, step: int) -> np.ndarray:
        env, student = self.env, self.student
        x = student.context(obs) if student is not None else None  # the student's input, built as when deployed
        if step >= env.episode_steps - self.spec.horizon:
            label, scores = search_values(env, self.goto, obs, step, self.spec.draws, self.seed)
            own = self.goto.act(obs, step)
            self.searched += 1
        else:
            label = own = self.goto.act(obs, step)
            scores = _UNSEARCHED
        self.goto_labels.append(own)
        self.values.append(scores)
        action = label
        if x is not None:
            self.inputs.append(x)
            chosen = student.act_batch(x[None])[0]
            action = (int(chosen[0]), int(chosen[1]))
            self.agreed += int(action == label)
        self.goto.taken(action)
        self.labels.append(label)
        return np.array(action)


def _episode(worker: _Worker, seed: int) -> EpisodeRecord:
    teacher = _Teacher(worker, seed)
    rewards: list[float] = []
    outcome = run_episode(worker.env, teacher, seed,
                          on_step=lambda step, action, obs, info: rewards.append(
                              info["reward_state"] + info["reward_progress"]))
    return EpisodeRecord(np.asarray(teacher.inputs, dtype=np.float32), np.asarray(teacher.labels, dtype=np.int64),
                         np.asarray(teacher.goto_labels, dtype=np.int64),
                         np.asarray(teacher.values, dtype=np.float32), np.asarray(rewards, dtype=np.float64),
                         outcome.final_R, teacher.agreed, teacher.searched)


def run_episodes(spec: WorkerSpec, student: Path, seeds: list[int], workers: int,
                 should_stop: Callable[[], bool]) -> Iterator[EpisodeRecord]:
    """The episodes of ``seeds``, driven by ``student`` and labelled by the teacher, as
    they finish (in any order); stops early when ``should_stop()``."""
    with WorkerPool(_worker, (spec, str(student)), workers) as pool:
        for record in pool.imap_unordered(_episode, seeds):
            yield record
            if should_stop():
                return
