"""Features computed from the thesis observation, inside the policy network.

The policy's input stays exactly the thesis observation (position, quaternion, last
command). This module turns it into quantities a small MLP can use without first
learning quaternion algebra: the body's rotation matrix, and the vector to the origin
expressed in the body frame (its direction and length). They are a deterministic function
of the observation, written in torch, so they are part of the exported ONNX graph.

Layout of the features (``FEATURE_NAMES``): position (3), rotation matrix row-major (9),
goal vector in the body frame (3), its direction (3), planar distance to the origin (1),
last command (2).

A policy with the ``context`` input (:data:`tumblebot.sim.policy.LAYOUTS`) gets those
features of the current and of the previous observation, then the design scaled by
``1/DESIGN_SCALE``, the fraction of the episode left, and the step's planar displacement
scaled the same way (``CONTEXT_FEATURE_NAMES``). A ``memory`` policy gets those, then
goto's motion estimates (the step length scaled the same way, the two spin rates in rad;
``MEMORY_FEATURE_NAMES``). A ``residual`` policy gets those, then goto's proposed action,
each leg's command one-hot (``RESIDUAL_FEATURE_NAMES``); a ``dual`` policy then the second
goto's action the same way and the design's reach ``l / r − 1`` (``DUAL_FEATURE_NAMES``).
:class:`ContextObservation` builds any of these inputs inside the training environments
with the same :class:`ObservationContext` the deployed policy uses.
"""

from __future__ import annotations

from typing import Any, cast

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from tumblebot.sim.observation import COMMAND, LAYOUTS, POSITION, QUATERNION, fields_slice
from tumblebot.sim.policy import ObservationContext

FEATURE_NAMES: tuple[str, ...] = (
    "px", "py", "pz",
    "r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22",
    "goal_bx", "goal_by", "goal_bz",
    "goal_dir_bx", "goal_dir_by", "goal_dir_bz",
    "goal_distance",
    "cmd_right", "cmd_left",
)
CONTEXT_FEATURE_NAMES: tuple[str, ...] = (
    *FEATURE_NAMES, *(f"prev_{name}" for name in FEATURE_NAMES),
    "design_x", "design_y", "design_z", "design_l", "steps_left", "moved_x", "moved_y",
)
MEMORY_FEATURE_NAMES: tuple[str, ...] = (*CONTEXT_FEATURE_NAMES, "memory_step_length", "memory_spin_positive",
                                         "memory_spin_negative")
RESIDUAL_FEATURE_NAMES: tuple[str, ...] = (*MEMORY_FEATURE_NAMES, *(f"goto_{leg}_{command}" for leg in ("right", "left")
                                                                    for command in ("reverse", "stop", "forward")))
DUAL_FEATURE_NAMES: tuple[str, ...] = (*RESIDUAL_FEATURE_NAMES, *(f"goto2_{leg}_{command}" for leg in ("right", "left")
                                                                  for command in ("reverse", "stop", "forward")),
                                       "design_reach")
_DIRECTION_SOFTENING = 0.05  #: m; keeps the direction finite at the goal
DESIGN_SCALE = 0.25  #: m; design lengths and step displacements are divided by it
#: Where each part of a design-conditioned input lies, asked of the layouts by name
_CURRENT = fields_slice("context", "px", "cmd_left")
_DESIGN = fields_slice("context", "design_x", "design_l")
_STEPS_LEFT = fields_slice("context", "steps_left", "steps_left")
_PREVIOUS = fields_slice("context", "prev_px", "prev_cmd_left")


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
        direction = goal_body / (distance + _DIRECTION_SOFTENING)
        return torch.cat([position, rot.reshape(-1, 9), goal_body, direction, distance, obs[:, COMMAND]], dim=-1)


class ContextFeatures(nn.Module):
    """``context`` input ``(B, 23)`` → features ``(B, 49)`` (``CONTEXT_FEATURE_NAMES``)."""

    def __init__(self) -> None:
        super().__init__()
        self.thesis = ObservationFeatures()

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        current, previous = obs[:, _CURRENT], obs[:, _PREVIOUS]
        design, steps_left = obs[:, _DESIGN], obs[:, _STEPS_LEFT]
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
    otherwise have to compute from ``x, y, z, l`` itself."""

    def __init__(self) -> None:
        super().__init__(proposals=2)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        design = obs[:, _DESIGN]
        radius = 0.5 * torch.sqrt(design[:, 1:2] ** 2 + design[:, 2:3] ** 2).clamp_min(1e-3)
        return torch.cat([super().forward(obs), design[:, 3:4] / radius - 1.0], dim=-1)


_FEATURES: dict[str, tuple[type[nn.Module], tuple[str, ...]]] = {
    "thesis": (ObservationFeatures, FEATURE_NAMES), "context": (ContextFeatures, CONTEXT_FEATURE_NAMES),
    "memory": (MemoryFeatures, MEMORY_FEATURE_NAMES), "residual": (ResidualFeatures, RESIDUAL_FEATURE_NAMES),
    "dual": (DualFeatures, DUAL_FEATURE_NAMES),
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
        high = np.full(len(LAYOUTS[layout]), 100.0, dtype=np.float32)
        self.observation_space = gym.spaces.Box(low=-high, high=high, dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self.context.reset(self._tumbler.design.as_tuple())
        return self.context(obs), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self.context(obs), float(reward), bool(terminated or truncated), False, info
