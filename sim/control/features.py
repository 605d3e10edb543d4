"""The policies' feature layer: what the network computes from its input before its MLP.

A policy's input is one of the observation layouts (:mod:`tumblebot.sim.observation`);
its first layer turns that into quantities a small MLP can use without first learning
quaternion algebra: the body's rotation matrix, and the vector to the origin expressed in
the body frame (its direction and length). The layer has no weights. It is declared here,
once, by name (:data:`FEATURES`), and computed twice: in torch inside the trained network
(:mod:`tumblebot.training.features`, so it is part of every exported ONNX graph), and in
NumPy by :func:`compute` here, which :class:`~tumblebot.sim.control.policy.OnnxPolicy` runs ahead
of the graph's MLP alone: the feature layer is about 220 tiny graph nodes, each with
onnxruntime's per-call cost, and evaluation pays it at every step.

Layout of the thesis features (:data:`FEATURE_NAMES`): position (3), rotation matrix
row-major (9), goal vector in the body frame (3), its direction (3), planar distance to
the origin (1), last command (2). A ``context`` input gets those features of the current
and of the previous observation, then the design scaled by ``1/DESIGN_SCALE``, the
fraction of the episode left, and the step's planar displacement scaled the same way
(:data:`CONTEXT_FEATURE_NAMES`). A ``memory`` input gets those, then goto's motion
estimates (the step length scaled the same way, the two spin rates in rad). A
``residual`` input gets those, then goto's proposed action, each leg's command one-hot;
a ``dual`` input then the second goto's action the same way and the design's reach
``l / r − 1`` (leg length over the pivot radius; 0 where the legs just tumble the body).
"""

from __future__ import annotations

import numpy as np

from tumblebot.sim.observation import COMMAND, LAYOUTS, POSITION, QUATERNION, fields_slice

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
#: layout → the features its network computes, in order
FEATURES: dict[str, tuple[str, ...]] = {"thesis": FEATURE_NAMES, "context": CONTEXT_FEATURE_NAMES,
                                        "memory": MEMORY_FEATURE_NAMES, "residual": RESIDUAL_FEATURE_NAMES,
                                        "dual": DUAL_FEATURE_NAMES}
DIRECTION_SOFTENING = 0.05  #: m; keeps the direction finite at the goal
DESIGN_SCALE = 0.25  #: m; design lengths and step displacements are divided by it
#: Where each part of a design-conditioned input lies, asked of the layouts by name
CURRENT = fields_slice("context", "px", "cmd_left")
DESIGN = fields_slice("context", "design_x", "design_l")
STEPS_LEFT = fields_slice("context", "steps_left", "steps_left")
PREVIOUS = fields_slice("context", "prev_px", "prev_cmd_left")
MEMORY = slice(len(LAYOUTS["context"]), len(LAYOUTS["memory"]))
PROPOSALS = slice(len(LAYOUTS["memory"]), len(LAYOUTS["dual"]))  #: goto's, then the second goto's action


def _rotation_terms() -> tuple[np.ndarray, np.ndarray]:
    """``M, c`` with ``rot = vec(q qᵀ) · M + c``: the rotation matrix of a unit quaternion
    ``(x, y, z, w)``, row-major, as one product (each entry is ``c ± 2·q_i·q_j`` terms)."""
    index = {"x": 0, "y": 1, "z": 2, "w": 3}
    rows = ["-yy -zz", "+xy -zw", "+xz +yw", "+xy +zw", "-xx -zz", "+yz -xw", "+xz -yw", "+yz +xw", "-xx -yy"]
    m = np.zeros((16, 9), dtype=np.float32)
    for k, row in enumerate(rows):
        for term in row.split():
            m[4 * index[term[1]] + index[term[2]], k] += 2.0 if term[0] == "+" else -2.0
    c = np.array([1, 0, 0, 0, 1, 0, 0, 0, 1], dtype=np.float32)
    return m, c


_ROTATION, _IDENTITY = _rotation_terms()
_ONES = np.ones((4, 1), dtype=np.float32)


def _thesis(obs: np.ndarray) -> np.ndarray:
    """Thesis observations ``(B, 9)`` → ``(B, 21)``."""
    q = obs[:, QUATERNION]
    q = q / np.maximum(np.sqrt((q * q) @ _ONES[:4]), np.float32(1e-8))  # a product sums faster than np.sum
    rot = (q[:, :, None] * q[:, None, :]).reshape(len(obs), 16) @ _ROTATION + _IDENTITY
    to_goal = -obs[:, 0:2]  # in the world, in the plane (its z is 0)
    goal_body = to_goal[:, 0:1] * rot[:, 0:3] + to_goal[:, 1:2] * rot[:, 3:6]  # rotᵀ · (gx, gy, 0)
    distance = np.sqrt((to_goal * to_goal) @ _ONES[:2])
    direction = goal_body / (distance + np.float32(DIRECTION_SOFTENING))
    return np.concatenate([obs[:, POSITION], rot, goal_body, direction, distance, obs[:, COMMAND]], axis=1)


def compute(layout: str, inputs: np.ndarray) -> np.ndarray:
    """The features of ``(B, N)`` float32 inputs in ``layout``, ``(B, len(FEATURES[layout]))`` float32."""
    x = np.asarray(inputs, dtype=np.float32)
    if layout == "thesis":
        return _thesis(x)
    current, previous, design = x[:, CURRENT], x[:, PREVIOUS], x[:, DESIGN]
    scale = np.float32(DESIGN_SCALE)
    both = _thesis(np.concatenate([current, previous]))  # one pass over both observations
    parts = [both[:len(x)], both[len(x):], design / scale, x[:, STEPS_LEFT],
             (current[:, 0:2] - previous[:, 0:2]) / scale]
    if layout != "context":
        memory = x[:, MEMORY]
        parts.extend([memory[:, 0:1] / scale, memory[:, 1:3]])
    if layout in ("residual", "dual"):
        proposals = x[:, PROPOSALS][:, :2 if layout == "residual" else 4]
        one_hot = np.abs(proposals[:, :, None] - np.arange(3, dtype=np.float32)) < np.float32(0.5)
        parts.append(one_hot.reshape(len(x), -1).astype(np.float32))
    if layout == "dual":
        radius = np.float32(0.5) * np.maximum(np.sqrt(design[:, 1:2] ** 2 + design[:, 2:3] ** 2), np.float32(1e-3))
        parts.append(design[:, 3:4] / radius - np.float32(1.0))
    out: np.ndarray = np.concatenate(parts, axis=1)
    return out
