"""Features computed from the thesis observation, inside the policy network.

The policy's input stays exactly the thesis observation (position, quaternion, last
command). This module turns it into quantities a small MLP can use without first
learning quaternion algebra: the body's rotation matrix, and the vector to the origin
expressed in the body frame (its direction and length). They are a deterministic function
of the observation, written in torch, so they are part of the exported ONNX graph.

Layout of the features (``FEATURE_NAMES``): position (3), rotation matrix row-major (9),
goal vector in the body frame (3), its direction (3), planar distance to the origin (1),
last command (2).
"""

from __future__ import annotations

import gymnasium as gym
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

FEATURE_NAMES: tuple[str, ...] = (
    "px", "py", "pz",
    "r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22",
    "goal_bx", "goal_by", "goal_bz",
    "goal_dir_bx", "goal_dir_by", "goal_dir_bz",
    "goal_distance",
    "cmd_right", "cmd_left",
)
_DIRECTION_SOFTENING = 0.05  #: m; keeps the direction finite at the goal


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
        position = obs[:, 0:3]
        rot = rotation_matrix(obs[:, 3:7])
        to_goal = torch.cat([-position[:, 0:2], torch.zeros_like(position[:, 0:1])], dim=-1)
        goal_body = torch.bmm(rot.transpose(1, 2), to_goal.unsqueeze(-1)).squeeze(-1)
        distance = torch.linalg.vector_norm(to_goal, dim=-1, keepdim=True)
        direction = goal_body / (distance + _DIRECTION_SOFTENING)
        return torch.cat([position, rot.reshape(-1, 9), goal_body, direction, distance, obs[:, 7:9]], dim=-1)


class TumblerFeaturesExtractor(BaseFeaturesExtractor):
    """SB3 features extractor wrapping :class:`ObservationFeatures`."""

    def __init__(self, observation_space: gym.spaces.Box) -> None:
        super().__init__(observation_space, features_dim=len(FEATURE_NAMES))
        self.features = ObservationFeatures()

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return self.features(observations)
