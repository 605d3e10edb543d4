"""Training hyperparameters: a typed config saved next to every run as ``config.json``."""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from tumblebot.errors import TumblebotError
from tumblebot.sim.control.policy import LAYOUTS
from tumblebot.sim.errors import SimError
from tumblebot.sim.world.constants import STALL_TORQUE
from tumblebot.sim.world.physics import PhysicsProfile
from tumblebot.sim.world.randomization import Randomization


class TrainingError(TumblebotError):
    """A training run that cannot start or resume (bad config, missing checkpoint, …)."""


@dataclass(frozen=True)
class RewardWeights:
    """The environment's reward shaping: ``state · R(s) + progress · ΔΦ`` every step, plus
    ``final · R(s_T)`` on the last (see :class:`~tumblebot.sim.world.env.TumblerEnv`)."""

    state: float = 1.0
    progress: float = 5.0
    final: float = 0.0

    def env_kwargs(self) -> dict[str, Any]:
        """The weights as :class:`~tumblebot.sim.world.env.TumblerEnv`'s keyword arguments."""
        return {"state_weight": self.state, "progress_weight": self.progress, "final_weight": self.final}


@dataclass
class TrainConfig:
    """Everything that defines a training run. Defaults are the ones the bundled policies
    used unless their model card says otherwise.

    Attributes:
        task: task short name.
        total_steps: environment steps to train for (all environments together).
        n_envs: parallel environments (``SubprocVecEnv``); 0 means one per CPU core.
        seed: seeds the environments and PPO.
        checkpoint_every: environment steps between checkpoints.
        learning_rate, n_steps, batch_size, n_epochs, gamma, gae_lambda, clip_range,
        ent_coef, vf_coef, max_grad_norm: PPO (stable-baselines3 names and meanings);
            ``n_steps`` is per environment.
        net_arch: hidden layer sizes of the policy and value MLPs (separate networks).
        state_weight, progress_weight, final_weight: the environment's reward shaping
            (:mod:`tumblebot.sim.world.env`); ``0, 0, 1`` trains on the final state's R alone.
        tumbling_designs_only: draw training designs only among those whose legs can tumble
            the body (:class:`~tumblebot.sim.world.randomization.Randomization`); off in the
            runs behind the bundled policies except where their card's config says so.
        init_from: checkpoint whose policy and value weights started this run (a warm
            start from another task's run, ``tumblebot train --init-from``), or None.
        init_from_steps: training steps that checkpoint had already taken.
        warm_start_temperature: with ``init_from``, divide the warm start's action logits by
            this (at least 1). The most likely action, so the deterministic policy, stays the
            same, but a student fitted to a teacher's labels, sure of every action, then
            explores in its rollouts, which PPO needs to improve on it; above 1 the value head
            also starts from zero (a student's value head was never fitted to this reward).
        observation: the policy's input layout, ``"thesis"`` (the thesis's 9 numbers) or
            ``"context"`` (those plus the design, the steps left and the previous
            observation) or ``"memory"`` (``context`` plus goto's motion estimates) or
            ``"residual"`` (``memory`` plus goto's proposed action) or ``"dual"``
            (``residual`` plus a second goto's, :data:`tumblebot.sim.observation.DUAL_GOTO`)
            or ``"dual-plan"`` (the same fields from two gotos with ``plan``'s estimates)
            or ``"tri-plan"`` (``dual-plan`` plus a third goto's,
            :data:`tumblebot.sim.observation.PLAN_SHORT_GOTO`;
            :data:`tumblebot.sim.control.policy.LAYOUTS`).
        motor_model, stall_torque: the servo the policy is trained under (see
            :mod:`tumblebot.sim.world.env`); recorded in the model card, and a policy is not used
            under another servo unless asked to.
        design: train on this one body ``[x, y, z, l]`` (metres) instead of a new design
            every episode: a policy retrained on a chosen robot (the reproduction's
            retrain check); None for the bundled policies.
    """

    task: str = "nav-flat"
    total_steps: int = 2_000_000
    n_envs: int = 0
    seed: int = 0
    checkpoint_every: int = 50_000
    learning_rate: float = 3e-4
    n_steps: int = 256
    batch_size: int = 256
    n_epochs: int = 10
    gamma: float = 0.98
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.005
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    net_arch: list[int] = field(default_factory=lambda: [128, 128])
    state_weight: float = RewardWeights.state
    progress_weight: float = RewardWeights.progress
    final_weight: float = RewardWeights.final
    tumbling_designs_only: bool = False
    motor_model: str = "dc"
    stall_torque: float = STALL_TORQUE
    observation: str = "thesis"
    init_from: str | None = None
    init_from_steps: int = 0
    warm_start_temperature: float = 1.0
    design: list[float] | None = None
    #: the whole physics profile when it differs from ``thesis`` in more than the servo
    #: above (:meth:`tumblebot.sim.world.physics.PhysicsProfile.as_fields`); None for runs before profiles
    physics: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        from tumblebot.sim.world.tasks import get_task

        get_task(self.task)
        _check_design(self.design)
        self._check_numbers()
        if self.init_from is not None and (not isinstance(self.init_from, str) or not self.init_from):
            raise TrainingError(f"training config init_from={self.init_from!r} must be a checkpoint path or null")
        if not isinstance(self.init_from_steps, int) or self.init_from_steps < 0:
            raise TrainingError(f"training config init_from_steps={self.init_from_steps!r} must be >= 0")
        try:
            self.profile()  # checks motor_model and stall_torque too
        except SimError as exc:
            raise TrainingError(f"training config: {exc}") from None
        if self.observation not in LAYOUTS:
            raise TrainingError(f"observation {self.observation!r} must be one of: {', '.join(LAYOUTS)}")
        if not isinstance(self.tumbling_designs_only, bool):
            raise TrainingError(f"training config tumbling_designs_only={self.tumbling_designs_only!r} "
                                "must be true or false")
        if not self.net_arch or any(not isinstance(n, int) or n < 1 for n in self.net_arch):
            raise TrainingError(f"training config net_arch={self.net_arch!r} must be a list of positive integers")

    def _check_numbers(self) -> None:
        """Counts are positive integers, rates and weights finite numbers in range."""
        for name in ("total_steps", "checkpoint_every", "n_steps", "batch_size", "n_epochs"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise TrainingError(f"training config {name}={value!r} must be a positive integer")
        if not isinstance(self.n_envs, int) or self.n_envs < 0:
            raise TrainingError(f"training config n_envs={self.n_envs!r} must be >= 0 (0 = one per core)")
        for name in ("learning_rate", "gamma", "gae_lambda", "clip_range", "max_grad_norm"):
            value = getattr(self, name)
            if not _finite(value) or not value > 0:
                raise TrainingError(f"training config {name}={value!r} must be a positive number")
        if not _finite(self.warm_start_temperature) or self.warm_start_temperature < 1:
            raise TrainingError(f"training config warm_start_temperature={self.warm_start_temperature!r} "
                                "must be a number >= 1")
        for name in ("gamma", "gae_lambda"):
            if getattr(self, name) > 1:
                raise TrainingError(f"training config {name}={getattr(self, name)!r} must be at most 1")
        for name in ("ent_coef", "vf_coef", "state_weight", "progress_weight", "final_weight"):
            value = getattr(self, name)
            if not _finite(value) or value < 0:
                raise TrainingError(f"training config {name}={value!r} must be a number >= 0")

    def profile(self) -> PhysicsProfile:
        """The physics profile the policy is trained under."""
        if self.physics is not None and not isinstance(self.physics, dict):
            raise TrainingError(f"training config physics={self.physics!r} must be a profile object or null")
        return PhysicsProfile.of_fields(self.motor_model, self.stall_torque, self.physics)

    def reward_weights(self) -> RewardWeights:
        """The environments' reward shaping."""
        return RewardWeights(self.state_weight, self.progress_weight, self.final_weight)

    def randomization(self) -> Randomization:
        """What the training environments randomise (the model card records the same)."""
        return self.profile().randomization(Randomization(tumbling_designs_only=self.tumbling_designs_only))

    @property
    def envs(self) -> int:
        return self.n_envs or (os.cpu_count() or 1)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2) + "\n"

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise TrainingError(f"unknown training config keys: {', '.join(unknown)}")
        return cls(**data)

    @classmethod
    def load(cls, path: Path) -> TrainConfig:
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise TrainingError(f"training config {path} does not exist") from None
        except json.JSONDecodeError as exc:
            raise TrainingError(f"training config {path} is not valid JSON: {exc}") from None
        if not isinstance(data, dict):
            raise TrainingError(f"training config {path} must hold a JSON object")
        return cls.from_dict(data)


def _check_design(design: object) -> None:
    """A fixed training design: None, or ``[x, y, z, l]`` within the bounds."""
    from tumblebot.sim.errors import DesignError
    from tumblebot.sim.world.design import Design

    if design is None:
        return
    if not isinstance(design, list) or len(design) != 4 \
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in design):
        raise TrainingError(f"training config design={design!r} must be [x, y, z, l] in metres or null")
    try:
        Design.from_sequence(design)
    except DesignError as exc:
        raise TrainingError(f"training config design: {exc}") from None


def _finite(value: object) -> bool:
    """A real number from a config file: not a boolean, not NaN or infinite."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
