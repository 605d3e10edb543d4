import math

import numpy as np
import pytest

from tumblebot.sim.world.frames import quat_multiply, to_lab_frame, to_task_frame, yaw_quaternion


def random_pose(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    q = rng.normal(size=4)
    return rng.uniform(-3, 3, 3), q / np.linalg.norm(q)


def test_that_the_identity_frame_changes_nothing() -> None:
    p, q = to_task_frame((1.0, 2.0, 0.1), (0.0, 0.0, 0.0, 1.0))
    np.testing.assert_allclose(p, [1.0, 2.0, 0.1])
    np.testing.assert_allclose(q, [0, 0, 0, 1])


def test_that_the_setpoint_becomes_the_origin_and_the_heading_becomes_plus_x() -> None:
    p, _ = to_task_frame((2.0, 3.0, 0.05), (0, 0, 0, 1), origin=(2.0, 2.0), heading=math.pi / 2)
    np.testing.assert_allclose(p, [1.0, 0.0, 0.05], atol=1e-12)  # 1 m along the heading is +x


@pytest.mark.parametrize("seed", range(5))
def test_that_moving_lab_and_robot_together_leaves_the_task_frame_pose_unchanged(seed: int) -> None:
    rng = np.random.default_rng(seed)
    p, q = random_pose(rng)
    origin, heading = rng.uniform(-2, 2, 2), rng.uniform(-math.pi, math.pi)
    task_p, task_q = to_task_frame(p, q, origin, heading)
    # the same robot placed in a lab rotated and shifted by (origin, heading)
    lab_p, lab_q = to_lab_frame(p, q, origin, heading)
    back_p, back_q = to_task_frame(lab_p, lab_q, origin, heading)
    np.testing.assert_allclose(back_p, p, atol=1e-12)
    assert abs(abs(np.dot(back_q, q)) - 1) < 1e-12
    again_p, _ = to_lab_frame(task_p, task_q, origin, heading)
    np.testing.assert_allclose(again_p, p, atol=1e-12)


def test_that_yaw_composes() -> None:
    q = quat_multiply(yaw_quaternion(0.3), yaw_quaternion(0.4))
    np.testing.assert_allclose(q, yaw_quaternion(0.7), atol=1e-12)
