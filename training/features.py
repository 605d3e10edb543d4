"""The policies' feature layer in torch, inside the policy network, and the training
environments' observation wrapper.

The features are declared, by name, in :mod:`tumblebot.sim.control.features` (which also computes
them, in plain Python, for :class:`~tumblebot.sim.control.policy.OnnxPolicy`); here they are computed in
torch, so they are part of the trained network and of every exported ONNX graph, and the
policy's input stays the observation layout it was trained on.
:class:`ContextObservation` builds any design-conditioned input inside the training
environments with the same :class:`ObservationContext` the deployed policy uses.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any, cast

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from tumblebot.sim.control.features import (
    CONTEXT_FEATURE_NAMES,
    CURRENT,
    DESIGN,
    DESIGN_SCALE,
    DIRECTION_SOFTENING,
    DUAL_FEATURE_NAMES,
    FEATURE_NAMES,
    FEATURES,
    MEMORY_FEATURE_NAMES,
    PREVIOUS,
    RESIDUAL_FEATURE_NAMES,
    STEPS_LEFT,
    TRI_FEATURE_NAMES,
)
from tumblebot.sim.control.policy import ObservationContext
from tumblebot.sim.observation import COMMAND, LAYOUTS, POSITION, QUATERNION

__all__ = ["CONTEXT_FEATURE_NAMES", "DESIGN_SCALE", "DUAL_FEATURE_NAMES", "FEATURE_NAMES", "MEMORY_FEATURE_NAMES",
           "RESIDUAL_FEATURE_NAMES", "TRI_FEATURE_NAMES", "ContextFeatures", "ContextObservation", "DualFeatures",
           "MemoryFeatures", "ObservationFeatures", "ResidualFeatures", "TriFeatures", "TumblerFeaturesExtractor",
           "feature_names", "features_for", "rotation_matrix"]


def rotation_matrix(q: torch.Tensor) -> torch.Tensor:
    """``(B, 4)`` quaternions ``(x, y, z, w)`` → ``(B, 3, 3)`` rotation matrices."""
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True).clamp_min(1e-8)
    x, y, z, w = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(-1, 3, 3)


class ObservationFeatures(nn.Module):
    """Thesis observation ``(B, 9)`` → features ``(B, 21)``."""

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        position = obs[:, POSITION]
        rot = rotation_matrix(obs[:, QUATERNION])
        to_goal = torch.cat([-position[:, 0:2], torch.zeros_like(position[:, 0:1])], dim=-1)
        goal_body = torch.bmm(rot.transpose(1, 2), to_goal.unsqueeze(-1)).squeeze(-1)
        distance = torch.linalg.vector_norm(to_goal, dim=-1, keepdim=True)
        direction = goal_body / (distance + DIRECTION_SOFTENING)
        return torch.cat([position, rot.reshape(-1, 9), goal_body, direction, distance, obs[:, COMMAND]], dim=-1)


class ContextFeatures(nn.Module):
    """``context`` input ``(B, 23)`` → features ``(B, 49)`` (``CONTEXT_FEATURE_NAMES``)."""

    def __init__(self) -> None:
        super().__init__()
        self.thesis = ObservationFeatures()

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        current, previous = obs[:, CURRENT], obs[:, PREVIOUS]
        design, steps_left = obs[:, DESIGN], obs[:, STEPS_LEFT]
        moved = (current[:, 0:2] - previous[:, 0:2]) / DESIGN_SCALE
        return torch.cat([self.thesis(current), self.thesis(previous), design / DESIGN_SCALE, steps_left, moved],
                         dim=-1)


class MemoryFeatures(nn.Module):
    """``memory`` input ``(B, 26)`` → features ``(B, 52)`` (``MEMORY_FEATURE_NAMES``)."""

    def __init__(self) -> None:
        super().__init__()
        self.context = ContextFeatures()
        self._context_size = len(LAYOUTS["context"])

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        memory = obs[:, self._context_size:]
        scaled = torch.cat([memory[:, 0:1] / DESIGN_SCALE, memory[:, 1:3]], dim=-1)
        return torch.cat([self.context(obs[:, :self._context_size]), scaled], dim=-1)


class ResidualFeatures(nn.Module):
    """``residual`` input ``(B, 28)`` → features ``(B, 58)`` (``RESIDUAL_FEATURE_NAMES``):
    the memory features, then each leg of goto's proposed action one-hot. With
    ``proposals=2`` the same for both of a ``dual`` input's proposals (:class:`DualFeatures`)."""

    def __init__(self, proposals: int = 1) -> None:
        super().__init__()
        self.memory = MemoryFeatures()
        self._memory_size = len(LAYOUTS["memory"])
        self._proposals = proposals

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        proposals = obs[:, self._memory_size:self._memory_size + 2 * self._proposals]
        one_hot = [(torch.abs(proposals[:, leg:leg + 1] - command) < 0.5).to(obs.dtype)
                   for leg in range(2 * self._proposals) for command in range(3)]
        return torch.cat([self.memory(obs[:, :self._memory_size]), *one_hot], dim=-1)


class DualFeatures(ResidualFeatures):
    """``dual`` input ``(B, 30)`` → features ``(B, 65)`` (``DUAL_FEATURE_NAMES``): the two
    proposals one-hot, then the design's reach, ``l / r − 1`` (leg length over the pivot
    radius; 0 where the legs just tumble the body), in which the better of the two gotos
    changes over (``tumblebot.training.choice``) and which a small tanh network would
    otherwise have to compute from ``x, y, z, l`` itself. With ``proposals=3`` the same
    for a ``tri-plan`` input ``(B, 32)`` → ``(B, 71)`` (:class:`TriFeatures`)."""

    def __init__(self, proposals: int = 2) -> None:
        super().__init__(proposals=proposals)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        design = obs[:, DESIGN]
        radius = 0.5 * torch.sqrt(design[:, 1:2] ** 2 + design[:, 2:3] ** 2).clamp_min(1e-3)
        return torch.cat([super().forward(obs), design[:, 3:4] / radius - 1.0], dim=-1)


class TriFeatures(DualFeatures):
    """``tri-plan`` input ``(B, 32)`` → features ``(B, 71)`` (``TRI_FEATURE_NAMES``): the
    three proposals one-hot, then the design's reach."""

    def __init__(self) -> None:
        super().__init__(proposals=3)


_FEATURES: dict[str, tuple[type[nn.Module], tuple[str, ...]]] = {
    "thesis": (ObservationFeatures, FEATURES["thesis"]), "context": (ContextFeatures, FEATURES["context"]),
    "memory": (MemoryFeatures, FEATURES["memory"]), "residual": (ResidualFeatures, FEATURES["residual"]),
    "dual": (DualFeatures, FEATURES["dual"]), "dual-plan": (DualFeatures, FEATURES["dual-plan"]),
    "tri-plan": (TriFeatures, FEATURES["tri-plan"]),
}


def feature_names(layout: str) -> tuple[str, ...]:
    """What the feature layer of a ``layout`` policy computes, in order."""
    return _FEATURES[layout][1]


def features_for(size: int) -> tuple[nn.Module, int]:
    """The feature layer for an input of ``size`` numbers, and its output size."""
    for layout, (module, names) in _FEATURES.items():
        if size == len(LAYOUTS[layout]):
            return module(), len(names)
    raise ValueError(f"no feature layer for a {size}-number observation")


class TumblerFeaturesExtractor(BaseFeaturesExtractor):
    """SB3 features extractor: the feature layer of the observation's layout, found by its size."""

    def __init__(self, observation_space: gym.spaces.Box) -> None:
        features, size = features_for(int(observation_space.shape[0]))
        super().__init__(observation_space, features_dim=size)
        self.features = features

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        features: torch.Tensor = self.features(observations)
        return features


class ContextObservation(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """A training environment whose observation is a ``context``, ``memory`` or ``residual`` layout.

    The input is built by :class:`ObservationContext`, exactly as :class:`OnnxPolicy`
    builds it when deployed. Since the steps left are part of the observation, the end
    of the episode is a true terminal state here (``terminated``), not a time-limit
    truncation to bootstrap across.
    """

    def __init__(self, env: gym.Env[np.ndarray, np.ndarray], layout: str = "context") -> None:
        super().__init__(env)
        self._tumbler: Any = cast(Any, env.unwrapped)  # a TumblerEnv: its design and episode length
        steps = int(self._tumbler.episode_steps)
        self.context = ObservationContext(layout, episode_steps=steps)
        self._last = np.zeros(len(LAYOUTS[layout]), dtype=np.float32)  # the observation last returned
        high = np.full(len(LAYOUTS[layout]), 100.0, dtype=np.float32)
        self.observation_space = gym.spaces.Box(low=-high, high=high, dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self.context.reset(self._tumbler.design.as_tuple())
        self._last = self.context(obs)
        return self._last, info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._last = self.context(obs)
        return self._last, float(reward), bool(terminated or truncated), False, info

    @property
    def episode_steps(self) -> int:
        return int(self._tumbler.episode_steps)

    # ------------------------------------------------- snapshots (planning, analysis)
    def snapshot(self) -> ContextSnapshot:
        """The simulation (:meth:`TumblerEnv.snapshot`) with the input's memory of the
        episode and the observation last returned: :meth:`restore` brings back all three,
        so a roll-out from it sees the inputs the episode would have. Free it with
        :meth:`release`."""
        return ContextSnapshot(self._tumbler.snapshot(), copy.deepcopy(self.context), self._last.copy())

    def restore(self, snap: ContextSnapshot) -> np.ndarray:
        """Return to ``snap`` (of this episode); returns the observation there."""
        self._tumbler.restore(snap.simulation)
        self.context = copy.deepcopy(snap.context)
        self._last = snap.observation.copy()
        return self._last.copy()

    def release(self, snap: ContextSnapshot) -> None:
        self._tumbler.release(snap.simulation)


@dataclass(frozen=True)
class ContextSnapshot:
    """What :meth:`ContextObservation.snapshot` saves."""

    simulation: Any  #: the :class:`TumblerEnv` snapshot
    context: ObservationContext  #: the input's memory, having seen ``observation``
    observation: np.ndarray  #: the observation last returned
