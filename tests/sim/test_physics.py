"""Physics profiles: the thesis's world as the built-in default, strict files, and the
environment running the profile's servo."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pybullet as p
import pytest

from tests.helpers import tb
from tumblebot.sim.world.env import TumblerEnv
from tumblebot.sim.world.physics import THESIS, PhysicsError, PhysicsProfile
from tumblebot.sim.world.randomization import Randomization


def test_that_the_thesis_profile_is_what_the_simulator_assumed_before_profiles() -> None:
    assert THESIS.randomization(Randomization()) == Randomization()
    env = TumblerEnv(randomization=Randomization.off())
    try:
        assert (env.motor_model, env.stall_torque, env.free_speed, env.hold_torque) == (
            THESIS.motor_model, THESIS.stall_torque, THESIS.free_speed, THESIS.hold_torque)
    finally:
        env.close()
    assert PhysicsProfile.load("thesis") is THESIS


def test_that_a_nominal_episode_runs_on_the_profiles_floor_not_the_thesiss() -> None:
    from tumblebot.sim.evaluation.episode import run_gait_episode
    from tumblebot.sim.world.design import THESIS_ROBOTS

    icy = PhysicsProfile(name="icy", friction=0.2)
    assert icy.nominal() == replace(Randomization.off(), friction=0.2)
    assert THESIS.nominal() == Randomization.off()
    runs = [run_gait_episode("distance-flat", THESIS_ROBOTS["3"], "forward", seed=1, randomize=False, physics=world)
            for world in (THESIS, icy, icy)]
    assert runs[1].final_position == runs[2].final_position  # nominal: nothing drawn
    assert runs[0].final_position != runs[1].final_position


def test_that_a_file_round_trips_and_the_digest_is_the_values_not_the_name(tmp_path: Path) -> None:
    lab = PhysicsProfile(name="lab", free_speed=3.1, stall_torque=0.9, friction=0.6, latency=(0.01, 0.08))
    lab.write(tmp_path / "lab.json")
    assert PhysicsProfile.load(str(tmp_path / "lab.json")) == lab
    renamed = PhysicsProfile(**{**lab.to_json(), "name": "other", "latency": lab.latency})
    assert renamed.digest() == lab.digest() != THESIS.digest()


def test_that_a_partial_file_takes_the_thesis_values_for_what_it_does_not_say(tmp_path: Path) -> None:
    (tmp_path / "floor.json").write_text('{"friction": 0.55}')
    floor = PhysicsProfile.load(str(tmp_path / "floor.json"))
    assert floor.friction == 0.55 and floor.name == "floor"
    assert floor.free_speed == THESIS.free_speed and floor.latency == THESIS.latency


@pytest.mark.parametrize("text, message", [
    ('{"stall": 1}', "unknown key(s) stall"),
    ('{"friction": NaN}', "friction nan must be a number"),
    ('{"free_speed": -3}', "free_speed -3 must be a number in (0, 50]"),
    ('{"stall_torque": 0}', "stall_torque 0 must be a number"),
    ('{"latency": [0.1, 0.05]}', "latency [0.1, 0.05] must be [lo, hi] seconds"),
    ('{"latency": 0.1}', "latency 0.1 must be [lo, hi]"),
    ('{"motor_model": "servo"}', "'servo' must be 'dc' or 'velocity'"),
    ('{"hold_torque": true}', "hold_torque True must be a number"),
    ('[1, 2]', "must be a JSON object"),
    ('{"friction": ', "not readable JSON"),
])
def test_that_a_bad_profile_is_refused_in_one_line_with_exit_2(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(PhysicsError):
        PhysicsProfile.load(str(path))
    run = tb("physics", "show", str(path))
    assert run.returncode == 2 and message in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1


def test_that_physics_show_prints_the_profile_and_a_catalogue_servo_gives_the_servo_keys() -> None:
    shown = tb("physics", "show", "thesis")
    assert shown.returncode == 0
    assert shown.stdout.splitlines()[0] == f"physics profile 'thesis' (digest {THESIS.digest()})"
    assert "  free_speed          3.67 rad/s" in shown.stdout
    micro = json.loads(tb("physics", "show", "thesis", "--servo", "feetech-fs90r", "--json").stdout)
    assert (micro["free_speed"], micro["stall_torque"]) == (13.6, 0.147)
    assert micro["friction"] == THESIS.friction
    missing = tb("physics", "show", "no-such-profile")
    assert missing.returncode == 2 and "not a built-in one (thesis) and no such file" in missing.stderr


@pytest.mark.parametrize("free_speed", [2.0, 4.5])
def test_that_the_environment_turns_the_legs_at_the_profiles_free_speed(free_speed: float) -> None:
    profile = PhysicsProfile(name="fast", motor_model="velocity", free_speed=free_speed, stall_torque=10.0,
                             motor_speed_sigma=0.0, latency=(0.0, 0.0))
    env = TumblerEnv(randomization=profile.randomization(Randomization.off()), **profile.env_kwargs())
    try:
        env.reset(seed=0)
        env.set_leg_commands(1.0, 1.0)
        env.advance(60)
        speeds = [p.getJointState(env.robot_id, j, physicsClientId=env.client_id)[1] for j in range(2)]
    finally:
        env.close()
    assert speeds == pytest.approx([free_speed, free_speed], rel=0.02)


def test_that_a_twin_record_keeps_the_hidden_world_for_the_consistency_check_alone(tmp_path: Path) -> None:
    from tumblebot.host.twin import twin_world_physics

    assert twin_world_physics(tmp_path) is None  # a set made before hidden worlds
    hidden = PhysicsProfile(name="hidden", free_speed=2.9, stall_torque=1.2, friction=0.6)
    (tmp_path / "twin.json").write_text(json.dumps({"servo": {"motor_model": "dc", "stall_torque": 0.582},
                                                    "world_physics": {**hidden.to_json(), "digest": hidden.digest()}}))
    assert twin_world_physics(tmp_path) == hidden


def test_that_twin_run_refuses_a_bad_world_profile_before_starting(tmp_path: Path) -> None:
    (tmp_path / "bad.json").write_text('{"free_speed": 0}')
    run = tb("twin", "run", "--out", str(tmp_path / "out"), "--world-physics", str(tmp_path / "bad.json"))
    assert run.returncode == 2 and "free_speed 0 must be a number" in run.stderr
    assert not (tmp_path / "out").exists()
