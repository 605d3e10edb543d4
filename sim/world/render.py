"""What a rendered frame shows beside the robot: a floor grid, the goal, the path so far and
the step with its reward, drawn over PyBullet's tiny-renderer image.

PyBullet's debug lines do not appear in ``getCameraImage`` without a GUI, so the marks are
projected with the camera's own view and projection matrices and drawn with Pillow.
Navigation is filmed from a fixed camera over the whole arena (a robot driving 5 m must be
seen to move); the other tasks follow the robot.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

Vec3 = tuple[float, float, float]

GRID_SPACING = 0.5  #: m between grid lines
ARENA = 2.5  #: half-width (m) of the navigation arena the fixed camera shows (starts lie within 2 m)
GRID_COLOUR = (150, 160, 175)
PATH_COLOUR = (220, 60, 40)
GOAL_COLOUR = (20, 150, 60)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: PyBullet's column-major view and projection matrices and the frame size."""

    view: tuple[float, ...]
    projection: tuple[float, ...]
    width: int
    height: int

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel ``(u, v)`` of each world point (n × 3); NaN for points behind the camera."""
        view = np.asarray(self.view, dtype=float).reshape(4, 4).T
        proj = np.asarray(self.projection, dtype=float).reshape(4, 4).T
        homogeneous = np.hstack([points, np.ones((len(points), 1))])
        clip = homogeneous @ (proj @ view).T
        w = clip[:, 3:4]
        with np.errstate(divide="ignore", invalid="ignore"):
            ndc = np.where(w > 1e-6, clip[:, :3] / w, np.nan)
        u = (ndc[:, 0] + 1.0) * 0.5 * self.width
        v = (1.0 - ndc[:, 1]) * 0.5 * self.height
        return np.stack([u, v], axis=1)


def camera_pose(navigation: bool, robot: Vec3) -> dict[str, object]:
    """``computeViewMatrixFromYawPitchRoll`` arguments: fixed over the arena for navigation,
    following the robot otherwise."""
    if navigation:
        return {"cameraTargetPosition": (0.0, -0.3, 0.0), "distance": 4.6, "yaw": 0.0, "pitch": -58.0,
                "roll": 0.0, "upAxisIndex": 2}
    return {"cameraTargetPosition": robot, "distance": 1.1, "yaw": 35.0, "pitch": -25.0, "roll": 0.0,
            "upAxisIndex": 2}


def _grid_lines(centre: tuple[float, float], half: float, ground: Callable[[float, float], float]
                ) -> list[np.ndarray]:
    """Polylines of the floor grid within ``half`` of ``centre``, following the ground's height."""
    cx = round(centre[0] / GRID_SPACING) * GRID_SPACING
    cy = round(centre[1] / GRID_SPACING) * GRID_SPACING
    ticks = np.arange(-half, half + 1e-9, GRID_SPACING)
    along = np.linspace(-half, half, 41)
    lines = []
    for t in ticks:
        xs, ys = np.full_like(along, cx + t), cy + along
        lines.append(np.stack([xs, ys, [ground(x, y) + 0.002 for x, y in zip(xs, ys, strict=True)]], axis=1))
        xs, ys = cx + along, np.full_like(along, cy + t)
        lines.append(np.stack([xs, ys, [ground(x, y) + 0.002 for x, y in zip(xs, ys, strict=True)]], axis=1))
    return lines


def annotate(image: np.ndarray, camera: Camera, *, navigation: bool, path: Sequence[Vec3],
             ground: Callable[[float, float], float], step: float, steps: int, reward: float) -> np.ndarray:
    """The frame with the grid, the goal (navigation), the path so far and a caption."""
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)

    def polyline(points: np.ndarray, colour: tuple[int, int, int], width: int) -> None:
        uv = camera.project(points)
        segment: list[tuple[float, float]] = []
        for u, v in uv:
            if np.isfinite(u) and np.isfinite(v):
                segment.append((float(u), float(v)))
            elif len(segment) > 1:
                draw.line(segment, fill=colour, width=width)
                segment = []
        if len(segment) > 1:
            draw.line(segment, fill=colour, width=width)

    robot = path[-1] if path else (0.0, 0.0, 0.0)
    centre = (0.0, 0.0) if navigation else (robot[0], robot[1])
    for line in _grid_lines(centre, ARENA if navigation else 1.5, ground):
        polyline(line, GRID_COLOUR, 1)
    if navigation:  # the goal: a ring of 0.1 m around the origin, and its centre
        angles = np.linspace(0.0, 2.0 * np.pi, 33)
        ring = np.stack([0.1 * np.cos(angles), 0.1 * np.sin(angles), np.full_like(angles, ground(0.0, 0.0) + 0.003)],
                        axis=1)
        polyline(ring, GOAL_COLOUR, 3)
        (u, v), = camera.project(np.array([[0.0, 0.0, ground(0.0, 0.0)]]))
        if np.isfinite(u) and np.isfinite(v):
            draw.ellipse((u - 3, v - 3, u + 3, v + 3), fill=GOAL_COLOUR)
    if len(path) > 1:
        polyline(np.asarray(path, dtype=float), PATH_COLOUR, 2)
    caption = f"step {step:4.1f}/{steps}   R = {reward:+.3f}" + ("   goal: green ring" if navigation else "")
    draw.rectangle((0, 0, camera.width, 16), fill=(255, 255, 255))
    draw.text((4, 2), caption, fill=(0, 0, 0))
    return np.asarray(picture, dtype=np.uint8)
