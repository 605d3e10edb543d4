"""The policies' feature layer: what the network computes from its input before its MLP.

A policy's input is one of the observation layouts (:mod:`tumblebot.sim.observation`);
its first layer turns that into quantities a small MLP can use without first learning
quaternion algebra: the body's rotation matrix, and the vector to the origin expressed in
the body frame (its direction and length). The layer has no weights. It is declared here,
once, by name (:data:`FEATURES`), and computed twice: in torch inside the trained network
(:mod:`tumblebot.training.features`, so it is part of every exported ONNX graph), and in
plain Python by :func:`compute` here, which :class:`~tumblebot.sim.control.policy.OnnxPolicy` runs ahead
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
``l / r − 1`` (leg length over the pivot radius; 0 where the legs just tumble the body);
a ``tri-plan`` input the three gotos' actions, then the reach.
"""

from __future__ import annotations

import math

import numpy as np

from tumblebot.sim.observation import GOTO_SETTINGS, LAYOUTS, fields_slice

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
TRI_FEATURE_NAMES: tuple[str, ...] = (*DUAL_FEATURE_NAMES[:-1], *(f"goto3_{leg}_{command}" for leg in ("right", "left")
                                                                 for command in ("reverse", "stop", "forward")),
                                      "design_reach")
#: layout → the features its network computes, in order
FEATURES: dict[str, tuple[str, ...]] = {"thesis": FEATURE_NAMES, "context": CONTEXT_FEATURE_NAMES,
                                        "memory": MEMORY_FEATURE_NAMES, "residual": RESIDUAL_FEATURE_NAMES,
                                        "dual": DUAL_FEATURE_NAMES, "dual-plan": DUAL_FEATURE_NAMES,
                                        "tri-plan": TRI_FEATURE_NAMES}
DIRECTION_SOFTENING = 0.05  #: m; keeps the direction finite at the goal
DESIGN_SCALE = 0.25  #: m; design lengths and step displacements are divided by it
#: Where each part of a design-conditioned input lies, asked of the layouts by name
CURRENT = fields_slice("context", "px", "cmd_left")
DESIGN = fields_slice("context", "design_x", "design_l")
STEPS_LEFT = fields_slice("context", "steps_left", "steps_left")
PREVIOUS = fields_slice("context", "prev_px", "prev_cmd_left")
MEMORY = slice(len(LAYOUTS["context"]), len(LAYOUTS["memory"]))
PROPOSALS = slice(len(LAYOUTS["memory"]), None)  #: goto's action, then each later goto's


def _thesis(o: list[float], out: list[float]) -> None:
    """Append the 21 thesis features of one observation ``o`` (9 numbers) to ``out``."""
    px, py, pz, qx, qy, qz, qw, right, left = o
    norm = max(math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw), 1e-8)
    x, y, z, w = qx / norm, qy / norm, qz / norm, qw / norm
    rot = (1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
           2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
           2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y))
    gx, gy = -px, -py  # to the goal, in the world; its z is 0
    goal = (gx * rot[0] + gy * rot[3], gx * rot[1] + gy * rot[4], gx * rot[2] + gy * rot[5])  # rotᵀ · (gx, gy, 0)
    distance = math.sqrt(gx * gx + gy * gy)
    soft = distance + DIRECTION_SOFTENING
    out += (px, py, pz, *rot, *goal, goal[0] / soft, goal[1] / soft, goal[2] / soft, distance, right, left)


def _row(layout: str, x: list[float]) -> list[float]:
    """The features of one input ``x`` in ``layout``."""
    out: list[float] = []
    if layout == "thesis":
        _thesis(x, out)
        return out
    current, previous = x[CURRENT], x[PREVIOUS]
    _thesis(current, out)
    _thesis(previous, out)
    out += (v / DESIGN_SCALE for v in x[DESIGN])
    out += x[STEPS_LEFT]
    out += ((current[0] - previous[0]) / DESIGN_SCALE, (current[1] - previous[1]) / DESIGN_SCALE)
    if layout == "context":
        return out
    step_length, spin_positive, spin_negative = x[MEMORY]
    out += (step_length / DESIGN_SCALE, spin_positive, spin_negative)
    gotos = len(GOTO_SETTINGS.get(layout, ()))
    for leg in x[PROPOSALS][:2 * gotos]:
        out += (float(abs(leg - command) < 0.5) for command in range(3))
    if gotos >= 2:
        _, y, z, length = x[DESIGN]
        out.append(length / (0.5 * max(math.sqrt(y * y + z * z), 1e-3)) - 1.0)
    return out


def compute(layout: str, inputs: np.ndarray) -> np.ndarray:
    """The features of ``(B, N)`` inputs in ``layout``, ``(B, len(FEATURES[layout]))`` float32.

    Row by row in plain floats: for the one input a step gives, a few dozen float
    operations cost less than the NumPy calls that would do them on arrays (the
    result agrees with the network's float32 arithmetic to about 1e-6)."""
    rows = np.asarray(inputs, dtype=np.float32).reshape(-1, len(LAYOUTS[layout])).tolist()
    return np.array([_row(layout, x) for x in rows], dtype=np.float32).reshape(len(rows), len(FEATURES[layout]))
