import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pybullet as p
import pytest

from tumblebot.sim.world import constants as C
from tumblebot.sim.world.design import THESIS_ROBOTS, Design
from tumblebot.sim.world.env import TumblerEnv
from tumblebot.sim.world.mass import DEFAULT_MASS_MODEL
from tumblebot.sim.world.robot import RobotModel, build_robot, to_urdf


@pytest.mark.parametrize("key", list(THESIS_ROBOTS))
def test_that_the_simulated_robot_weighs_what_the_mass_model_says(key: str) -> None:
    w = THESIS_ROBOTS[key]
    model = RobotModel.from_design(w)
    assert model.total_mass == pytest.approx(DEFAULT_MASS_MODEL.total_mass(w))
    client = p.connect(p.DIRECT)
    try:
        body = build_robot(client, model, (0, 0, 1), (0, 0, 0, 1))
        masses = [p.getDynamicsInfo(body, link, physicsClientId=client)[0] for link in (-1, 0, 1)]
        assert sum(masses) == pytest.approx(model.total_mass)
        inertia = p.getDynamicsInfo(body, -1, physicsClientId=client)[2]
        np.testing.assert_allclose(inertia, model.body_inertia, rtol=1e-6)
    finally:
        p.disconnect(client)


def test_that_the_exported_urdf_loads_in_pybullet_with_the_same_masses(tmp_path: Path) -> None:
    model = RobotModel.from_design(Design(0.25, 0.15, 0.12, 0.2))
    path = tmp_path / "robot.urdf"
    path.write_text(to_urdf(model))
    root = ET.parse(path).getroot()
    assert [j.get("type") for j in root.iter("joint")] == ["continuous", "continuous"]
    client = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(str(path), physicsClientId=client)
        assert p.getNumJoints(body, physicsClientId=client) == 2
        masses = [p.getDynamicsInfo(body, link, physicsClientId=client)[0] for link in (-1, 0, 1)]
        assert sum(masses) == pytest.approx(model.total_mass, rel=1e-5)
        damping = p.getJointInfo(body, 0, physicsClientId=client)[6]
        assert damping == pytest.approx(C.MOTOR_DAMPING, rel=1e-5)
    finally:
        p.disconnect(client)


def pinned_env() -> TumblerEnv:
    from tumblebot.sim.world.randomization import Randomization

    env = TumblerEnv(task="nav-flat", randomization=Randomization.off())
    env.reset(seed=0)
    p.changeDynamics(env.robot_id, -1, mass=0.0, physicsClientId=env.client_id)  # pin the body
    return env


def test_that_an_unloaded_leg_spins_at_the_free_speed_under_the_dc_model() -> None:
    """The DC line's free end: full command, no load (no gravity) gives γ̇ = 3.67 rad/s."""
    env = pinned_env()
    try:
        client, robot = env.client_id, env.robot_id
        p.setGravity(0, 0, 0, physicsClientId=client)
        p.resetBasePositionAndOrientation(robot, (0, 0, 1.0), (0, 0, 0, 1), physicsClientId=client)
        env.step(np.array([2, 0]))
        speeds = [s[1] for s in p.getJointStates(robot, [0, 1], physicsClientId=client)]
        assert speeds == pytest.approx([C.LEG_SPEED, -C.LEG_SPEED], rel=1e-3)
    finally:
        env.close()


def test_that_a_blocked_leg_pushes_with_the_stall_torque_under_the_dc_model() -> None:
    """The DC line's other end: a leg held still by the ground delivers ke·V/R ≈ 0.58 N·m."""
    env = pinned_env()
    try:
        client, robot = env.client_id, env.robot_id
        # Body pinned low enough that the legs, pointing down, press into the ground.
        z = env.design.l - 0.01
        p.resetBasePositionAndOrientation(robot, (0, 0, z), (0, 0, 0, 1), physicsClientId=client)
        for j, angle in enumerate((3.0, -3.0)):
            p.resetJointState(robot, j, angle, 0.0, physicsClientId=client)
        env.step(np.array([2, 0]))  # both legs driven further into the ground
        torques = [abs(s[3]) for s in p.getJointStates(robot, [0, 1], physicsClientId=client)]
        speeds = [abs(s[1]) for s in p.getJointStates(robot, [0, 1], physicsClientId=client)]
        assert max(speeds) < 0.05
        assert torques == pytest.approx([C.STALL_TORQUE] * 2, rel=0.05)
    finally:
        env.close()
