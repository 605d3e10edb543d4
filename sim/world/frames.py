"""Frame transformations between the lab (mocap) frame and a task's frame.

The tasks are posed toward the origin (navigation) or along +x (distance, incline). To
drive to any setpoint, or along any heading, the host expresses the robot's pose in a
*task frame*: translated so the setpoint (or the start) is the origin, and rotated about
the vertical so the desired heading is +x. Pure numpy: the host uses it without PyBullet.

Quaternions are ``(x, y, z, w)``, as in PyBullet and the observation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

Vector = Sequence[float] | np.ndarray


def quat_multiply(a: Vector, b: Vector) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of ``(x, y, z, w)`` quaternions."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


def yaw_quaternion(angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about +z."""
    return np.array([0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)])


def to_task_frame(position: Vector, quaternion: Vector, origin: Vector = (0.0, 0.0),
                  heading: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Lab-frame pose -> task-frame pose.

    Args:
        position: ``(x, y, z)`` in the lab frame, m.
        quaternion: orientation ``(x, y, z, w)`` in the lab frame.
        origin: the lab-frame ``(x, y)`` that becomes the task origin (the setpoint for
            navigation, the start for distance and incline).
        heading: the lab-frame direction (rad from +x, counter-clockwise) that becomes +x.
    """
    c, s = math.cos(-heading), math.sin(-heading)
    dx, dy = position[0] - origin[0], position[1] - origin[1]
    p = np.array([c * dx - s * dy, s * dx + c * dy, float(position[2])])
    q = quat_multiply(yaw_quaternion(-heading), quaternion)
    return p, q / np.linalg.norm(q)


def to_lab_frame(position: Vector, quaternion: Vector, origin: Vector = (0.0, 0.0),
                 heading: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`to_task_frame`."""
    c, s = math.cos(heading), math.sin(heading)
    p = np.array([c * position[0] - s * position[1] + origin[0], s * position[0] + c * position[1] + origin[1],
                  float(position[2])])
    q = quat_multiply(yaw_quaternion(heading), quaternion)
    return p, q / np.linalg.norm(q)
