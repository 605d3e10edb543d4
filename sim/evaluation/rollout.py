"""One episode rollout for the whole package, and the controllers it drives.

:func:`run_episode` (reset, then :func:`drive` to the episode's end) is the package's one
loop that steps an environment through an episode: :mod:`tumblebot.sim.evaluation.evaluate`
(one design, many episodes), :mod:`tumblebot.sim.evaluation.runner` (many designs, on the
worker pool), the scripted episodes, the teacher's choice sweep and the imitation teacher
all run on it; :func:`branch` continues an episode from a snapshot with another action at
one step (the imitation teacher's search and the policy-headroom reports). A
controller is made from its description (:class:`~tumblebot.sim.control.drivers.Driver`) by
:func:`make_actor`; every kind answers ``reset(seed, design)`` at the start of an episode
and ``act(obs, step)`` at each step, whatever it uses of them (a scripted gait only the
step and the seed, a ``thesis`` ONNX policy only the observation, a ``context`` one also
the design and its own memory, ``goto`` the observation, the step and its memory).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from tumblebot.sim.control.goto import GotoController, check_navigation_task, navigator
from tumblebot.sim.errors import SimError

if TYPE_CHECKING:
    from tumblebot.sim.control.policy import OnnxPolicy

Design4 = tuple[float, float, float, float]
StepCallback = Callable[[int, np.ndarray, np.ndarray, dict[str, Any]], None]


class Actor(Protocol):
    def reset(self, seed: int, design: Design4) -> None: ...

    def act(self, obs: np.ndarray, step: int) -> np.ndarray: ...


class PolicyActor:
    """An ONNX policy (:class:`~tumblebot.sim.control.policy.OnnxPolicy`): a file's, or
    ``policy`` as it is (one mid-episode whose memory a roll-out from a snapshot keeps)."""

    def __init__(self, policy: OnnxPolicy) -> None:
        self.policy = policy

    @classmethod
    def from_file(cls, path: Path, task: str) -> PolicyActor:
        from tumblebot.sim.control.policy import OnnxPolicy

        return cls(OnnxPolicy(path, task=task))

    def reset(self, seed: int, design: Design4) -> None:
        self.policy.reset(design)

    def act(self, obs: np.ndarray, step: int) -> np.ndarray:
        return self.policy.act(obs)


class _GaitActor:
    def __init__(self, name: str) -> None:
        from tumblebot.sim.control.gaits import get_gait

        self.gait = get_gait(name)
        self.rng = np.random.default_rng(0)

    def reset(self, seed: int, design: Design4) -> None:
        self.rng = np.random.default_rng(seed)  # the random gait's draws follow the episode

    def act(self, obs: np.ndarray, step: int) -> np.ndarray:
        return np.array(self.gait(step, self.rng))


class GotoActor:
    """``goto`` (:mod:`tumblebot.sim.control.goto`): a new controller with its default settings, or
    ``controller`` as it is (say, one with pinned settings, or one mid-episode whose memory
    a planner's roll-out from a snapshot keeps: :func:`drive` does not reset it)."""

    def __init__(self, controller: GotoController | None = None) -> None:
        self.goto = controller if controller is not None else GotoController()

    def reset(self, seed: int, design: Design4) -> None:
        self.goto.reset()

    def act(self, obs: np.ndarray, step: int) -> np.ndarray:
        return np.array(self.goto.act(obs, step))


def make_actor(kind: str, name: str, task: str) -> Actor:
    """``kind`` ``"onnx"`` (``name`` a policy file), ``"gait"`` (a gait name) or ``"goto"``
    (``name`` a navigation controller: ``goto`` or ``plan``)."""
    if kind == "onnx":
        return PolicyActor.from_file(Path(name), task)
    if kind == "gait":
        return _GaitActor(name)
    if kind == "goto":
        check_navigation_task(task)
        return GotoActor(navigator(name))
    raise SimError(f"unknown controller kind {kind!r}")


@dataclass(frozen=True)
class Outcome:
    """What an evaluation keeps of an episode."""

    final_R: float
    final_position: tuple[float, float, float]


def run_episode(env: Any, actor: Actor, seed: int, options: dict[str, Any] | None = None,
                on_step: StepCallback | None = None) -> Outcome:
    """Reset ``env`` with ``seed`` (and ``options``), drive it with ``actor`` to the end
    of the episode, and return the final-state reward and position. ``on_step(step,
    action, obs, info)`` sees every step, for callers that record the trajectory."""
    obs, _ = env.reset(seed=seed, options=options)
    actor.reset(seed, env.design.as_tuple())
    info = drive(env, actor, obs, 0, on_step)
    if "final_R" not in info:
        raise SimError("the episode ended without a final state (terminated early?)")
    pos = info["final_position"]
    return Outcome(float(info["final_R"]), (float(pos[0]), float(pos[1]), float(pos[2])))


def drive(env: Any, actor: Actor, obs: np.ndarray, step: int = 0,
          on_step: StepCallback | None = None) -> dict[str, Any]:
    """Drive ``env`` with ``actor`` from ``obs`` before step ``step`` to the end of the
    episode (mid-episode too: a planner continues from a snapshot); returns the last
    step's ``info``."""
    info: dict[str, Any] = {}
    for k in range(step, env.episode_steps):
        action = actor.act(obs, k)
        obs, _, terminated, truncated, info = env.step(action)
        if on_step is not None:
            on_step(k, action, obs, info)
        if terminated or truncated:
            break
    return info


def branch(env: Any, snapshot: Any, action: Any, actor: Actor, step: int,
           before_step: Callable[[], None] | None = None) -> dict[str, Any]:
    """The rest of an episode from ``snapshot`` (the simulation before step ``step``, taken
    with ``env.snapshot()``): ``action`` at that step, then ``actor`` to the end (it is not
    reset: the caller gives it the memory it had before the step, having seen ``action``
    taken). ``before_step()``, if given, runs once the snapshot is restored (say, to draw
    the motor noise to come anew). Returns the last step's ``info``; the snapshot stays
    usable (the caller releases it)."""
    env.restore(snapshot)
    if before_step is not None:
        before_step()
    obs, _, terminated, truncated, info = env.step(np.asarray(action))
    if terminated or truncated:
        return dict(info)
    return drive(env, actor, obs, step + 1)
