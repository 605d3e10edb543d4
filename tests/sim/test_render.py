"""Frames that show navigation: a fixed camera over the arena, the goal, a floor grid, the
path so far and the step with its reward."""

from __future__ import annotations

import numpy as np

from tumblebot.sim.evaluation.episode import run_gait_episode
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.render import GOAL_COLOUR, PATH_COLOUR, Camera

XI3 = Design(0.292, 0.129, 0.098, 0.136)


def _mask(frame: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
    mask: np.ndarray = np.abs(frame.astype(int) - np.array(colour)).sum(axis=2) < 30
    return mask


def test_that_a_navigation_video_shows_the_goal_grid_and_path_from_a_fixed_camera_regression_rocks_in_place(
        ) -> None:
    result = run_gait_episode("nav-flat", XI3, "goto", seed=3, record=True)
    first, last = result.frames[0], result.frames[-1]
    early = result.frames[30]  # 3 s in: the robot has moved, but not onto the goal yet
    goal_first, goal_early = np.argwhere(_mask(first, GOAL_COLOUR)), np.argwhere(_mask(early, GOAL_COLOUR))
    assert len(goal_first) > 10 and len(goal_early) > 10
    # a fixed camera: the goal is drawn at the same place while the robot moves
    assert np.allclose(goal_first.mean(axis=0), goal_early.mean(axis=0), atol=2)
    assert np.hypot(*np.subtract(result.steps[2].position[:2], result.steps[0].position[:2])) > 0.05
    assert _mask(last, PATH_COLOUR).sum() > _mask(first, PATH_COLOUR).sum() + 50  # the path grows
    caption = last[:16]
    assert (caption > 200).mean() > 0.7 and (caption < 60).any()  # a white bar with text


def test_that_camera_projection_matches_pybullet_image_geometry() -> None:
    import pybullet as p

    view = p.computeViewMatrixFromYawPitchRoll(cameraTargetPosition=(0, 0, 0), distance=3.0, yaw=0, pitch=-60,
                                               roll=0, upAxisIndex=2)
    proj = p.computeProjectionMatrixFOV(fov=60.0, aspect=4 / 3, nearVal=0.02, farVal=20.0)
    camera = Camera(tuple(view), tuple(proj), 320, 240)
    (u, v), = camera.project(np.array([[0.0, 0.0, 0.0]]))
    assert abs(u - 160) < 1 and abs(v - 120) < 1  # the target is the image centre
    (_, v2), = camera.project(np.array([[0.0, 1.0, 0.0]]))
    assert v2 < v  # farther along +y (away from the camera at yaw 0) is higher in the image
    behind = camera.project(np.array([[0.0, -10.0, 10.0]]))
    assert np.isnan(behind).all()
