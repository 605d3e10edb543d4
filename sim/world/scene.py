"""Building a task's scene in a PyBullet client: ground, terrain or ramp.

Scenes are rebuilt after ``resetSimulation`` every episode: re-creating bodies without it
leaks memory in PyBullet, ``resetSimulation`` does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tumblebot.sim.world.pb import pybullet
from tumblebot.sim.world.tasks import TaskSpec
from tumblebot.sim.world.terrain import TerrainConfig, height_at, tile_heightfield

INCLINE_ANGLE = math.radians(15.0)  #: the ramp's slope (thesis §2.3.3)
RAMP_LENGTH = 8.0  #: m along the slope
RAMP_THICKNESS = 0.5  #: m


@dataclass
class Scene:
    """What the environment needs to know about the ground it built."""

    task: TaskSpec
    heights: np.ndarray | None = None
    terrain: TerrainConfig | None = None

    def ground_height(self, x: float, y: float, radius: float) -> float:
        """Highest ground within ``radius`` of ``(x, y)``, for spawning above it."""
        if self.task.terrain == "perlin" and self.heights is not None and self.terrain is not None:
            return height_at(self.heights, self.terrain, x, y, radius)
        if self.task.terrain == "incline":
            return max(0.0, (x + radius) * math.tan(INCLINE_ANGLE))
        return 0.0


def build_scene(client: int, task: TaskSpec, rng: np.random.Generator, terrain: TerrainConfig,
                friction: float) -> Scene:
    """Create the task's static geometry in ``client`` (after ``resetSimulation``)."""
    p = pybullet()

    plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=client)
    # A thin box as the plane's visual (PyBullet has no default visual for planes).
    plane_visual = p.createVisualShape(p.GEOM_BOX, halfExtents=[25.0, 25.0, 0.0005],
                                       visualFramePosition=[0.0, 0.0, -0.0005],
                                       rgbaColor=[0.85, 0.88, 0.9, 1.0], physicsClientId=client)
    ground = p.createMultiBody(0.0, plane, plane_visual, physicsClientId=client)
    p.changeDynamics(ground, -1, lateralFriction=friction, physicsClientId=client)
    scene = Scene(task)
    if task.terrain == "perlin":
        heights = tile_heightfield(terrain, rng)
        shape = p.createCollisionShape(
            p.GEOM_HEIGHTFIELD,
            meshScale=[terrain.cell_size, terrain.cell_size, 1.0],
            heightfieldData=heights.ravel().tolist(),
            numHeightfieldRows=terrain.cells,
            numHeightfieldColumns=terrain.cells,
            physicsClientId=client,
        )
        # PyBullet centres a heightfield vertically on (min + max) / 2.
        mid = 0.5 * (float(heights.min()) + float(heights.max()))
        field = p.createMultiBody(0.0, shape, -1, basePosition=[0.0, 0.0, mid], physicsClientId=client)
        p.changeVisualShape(field, -1, rgbaColor=[0.55, 0.62, 0.5, 1.0], physicsClientId=client)
        p.changeDynamics(field, -1, lateralFriction=friction, physicsClientId=client)
        scene.heights, scene.terrain = heights, terrain
    elif task.terrain == "incline":
        half = [RAMP_LENGTH / 2, RAMP_LENGTH / 2, RAMP_THICKNESS / 2]
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
        visual = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[0.6, 0.6, 0.68, 1.0],
                                     physicsClientId=client)
        a = INCLINE_ANGLE
        along = np.array([math.cos(a), 0.0, math.sin(a)])
        normal = np.array([-math.sin(a), 0.0, math.cos(a)])
        # The top face's upper-left edge lies on the y axis: the ramp starts at the origin.
        centre = along * RAMP_LENGTH / 2 - normal * RAMP_THICKNESS / 2
        orn = p.getQuaternionFromEuler([0.0, -a, 0.0])
        ramp = p.createMultiBody(0.0, shape, visual, basePosition=centre.tolist(), baseOrientation=orn,
                                 physicsClientId=client)
        p.changeDynamics(ramp, -1, lateralFriction=friction, physicsClientId=client)
    return scene
