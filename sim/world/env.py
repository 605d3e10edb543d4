"""The tumbler environment: one base class, tasks differ only by their :class:`TaskSpec`.

Observation (``OBS_FIELDS``): base position (3, m), base orientation quaternion
(``qx, qy, qz, qw``), and the last command of each motor (−1, 0, +1). Action:
``MultiDiscrete([3, 3])``, per motor 0 = full reverse, 1 = stop, 2 = full forward, motor
order ``(right, left)`` (right = the leg on the body's +x side). One step is 1 s of
simulated time (240 physics substeps); an episode is 20 steps, then it is truncated.

Reward per step (training shaping; every term is in ``info``):
``state_weight · R(s_t) + progress_weight · (Φ(s_t) − Φ(s_{t−1}))`` with ``R`` the thesis
reward of the state and ``Φ`` the task's progress measure, plus ``final_weight · R(s_T)`` on
the last step. The evaluation metric is the thesis reward of the final state, reported as
``info["final_R"]`` on the last step; ``state_weight = progress_weight = 0, final_weight = 1``
trains on exactly that.

Motor models (``motor_model``):

* ``"dc"`` (default): the servo as a DC gear-motor, ``τ = τ_stall·(u − ω/γ̇)`` (with the
  thesis constants ``τ_stall = ke·V/R ≈ 0.582 N·m``, i.e. ``τ = ke·(u·V − ke·ω)/R``). It is
  applied each substep through a velocity motor whose target is the free speed and whose
  force limit is the DC torque at the current speed; that reproduces the torque–speed
  line exactly and stays stable for any leg inertia (an explicit viscous term does not).
* ``"velocity"``: a velocity controller at the free speed with the stall torque as
  force cap, the common approximation (cheaper: set once per command).

``stall_torque`` (N·m, default the thesis constants' 0.582) scales both models: the DC
line runs from it at standstill to zero at the free speed (``free_speed``, rad/s, default
the thesis's γ̇ = 3.67), and velocity control is capped at it. A physics profile
(:mod:`tumblebot.sim.world.physics`) gives all of these at once. A predecessor-like strong
servo is ``motor_model="velocity", stall_torque=10``.

"Stop" holds the leg with a velocity-zero motor limited to the back-EMF braking torque
plus ``hold_torque`` (gearbox friction and the servo's neutral-band braking).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from tumblebot.sim.errors import SimError
from tumblebot.sim.observation import OBS_LAYOUT
from tumblebot.sim.world import constants as C
from tumblebot.sim.world.design import THESIS_ROBOTS, Design
from tumblebot.sim.world.pb import pybullet
from tumblebot.sim.world.randomization import Randomization
from tumblebot.sim.world.robot import RobotModel, build_robot
from tumblebot.sim.world.scene import Scene, build_scene
from tumblebot.sim.world.tasks import TaskSpec, get_task
from tumblebot.sim.world.terrain import TerrainConfig

OBS_FIELDS: tuple[str, ...] = OBS_LAYOUT
OBS_INDEX: dict[str, int] = {name: i for i, name in enumerate(OBS_FIELDS)}
ACTION_LABELS: tuple[str, str, str] = ("reverse", "stop", "forward")
MotorModel = Literal["dc", "velocity"]

#: The design used when none is given and designs are not randomised: the thesis's ξ = 3 robot.
DEFAULT_DESIGN = THESIS_ROBOTS["3"]
_POSITION_LIMIT = 100.0
_JOINTS = (0, 1)


def _rel(rng: np.random.Generator, sigma: float, size: int | None = None) -> Any:
    """``1 + N(0, σ)`` clipped to ±3σ; always consumes the same number of draws."""
    draw = rng.standard_normal(size)
    return 1.0 + sigma * np.clip(draw, -3.0, 3.0)


@dataclass(frozen=True)
class _WorldDraws:
    """An episode's world draws: a fixed count in a fixed order, whatever the design and
    whatever is then used of them (common random numbers across designs)."""

    mass_scale: float
    leg_mass_scale: float
    inertia_scale: tuple[float, float, float]
    friction: float
    leg_angles: tuple[float, float]
    roll: float  #: rad: which long face the robot starts on
    yaw: float  #: rad, for a ring start
    yaw_jitter: float  #: rad, around +y for a start at the origin
    distance: float  #: m from the origin, for a ring start
    direction: float  #: rad, for a ring start

    @classmethod
    def draw(cls, rng: np.random.Generator, rnd: Randomization, start_distance: tuple[float, float]) -> _WorldDraws:
        mass_scale = float(_rel(rng, rnd.mass_rel_sigma))
        leg_mass_scale = float(_rel(rng, rnd.mass_rel_sigma))
        inertia = _rel(rng, rnd.inertia_rel_sigma, 3)
        friction = rnd.friction * float(_rel(rng, rnd.friction_rel_sigma))
        legs = rng.uniform(-math.pi, math.pi, 2)
        roll = int(rng.integers(4)) * math.pi / 2
        yaw = float(rng.uniform(0.0, 2 * math.pi))
        jitter = float(rng.uniform(-0.1, 0.1))
        distance = float(rng.uniform(*start_distance))
        direction = float(rng.uniform(0.0, 2 * math.pi))
        return cls(mass_scale, leg_mass_scale, (float(inertia[0]), float(inertia[1]), float(inertia[2])), friction,
                   (float(legs[0]), float(legs[1])), roll, yaw, jitter, distance, direction)

    def start(self, ring: bool, start_pose: bool, options: Mapping[str, Any]) -> tuple[tuple[float, float], float]:
        """Start position and yaw: on the ring or at the origin, unless ``options`` gives
        them (field-trial start points, the digital twin)."""
        if ring:
            xy = (self.distance * math.cos(self.direction), self.distance * math.sin(self.direction))
            yaw = self.yaw
        else:
            xy, yaw = (0.0, 0.0), math.pi / 2 + (self.yaw_jitter if start_pose else 0.0)
        given_xy, given_yaw = options.get("start_xy"), options.get("start_yaw")
        if given_xy is not None:
            xy = (float(given_xy[0]), float(given_xy[1]))
        if given_yaw is not None:
            yaw = float(given_yaw)
        return xy, yaw


def _check_servo(motor_model: str, stall_torque: float, free_speed: float) -> None:
    if motor_model not in ("dc", "velocity"):
        raise SimError(f"motor_model={motor_model!r} must be 'dc' or 'velocity'")
    if not (math.isfinite(stall_torque) and 0.0 < stall_torque <= C.MAX_STALL_TORQUE):
        raise SimError(f"stall_torque={stall_torque!r} N·m must be in (0, {C.MAX_STALL_TORQUE:g}]")
    if not (math.isfinite(free_speed) and free_speed > 0.0):
        raise SimError(f"free_speed={free_speed!r} rad/s must be positive")


@dataclass(frozen=True)
class EnvSnapshot:
    """What :meth:`TumblerEnv.snapshot` saves (the physics itself stays in the server)."""

    state_id: int
    motor_rng_state: Mapping[str, Any]
    command: np.ndarray
    speed: np.ndarray
    step: int
    potential: float
    substep_count: int


class TumblerEnv(gym.Env[np.ndarray, np.ndarray]):
    """A two-legged tumbling robot performing one of the four thesis tasks.

    Args:
        task: task short name (``nav-flat``, ``nav-terrain``, ``distance-flat``,
            ``incline``) or Gymnasium id.
        design: a fixed design; ``None`` draws one per episode when
            ``randomization.design`` is on, else uses :data:`DEFAULT_DESIGN`.
            ``reset(options={"design": w})`` overrides it for one episode;
            ``options={"start_xy": (x, y), "start_yaw": yaw}`` fixes where the robot starts
            (the random draws are still made, so other streams do not shift).
        randomization: what varies between episodes (:class:`Randomization`).
        motor_model: ``"dc"`` or ``"velocity"`` (see module docs).
        stall_torque: the servo's stall torque, N·m (see module docs).
        episode_steps: steps per episode (thesis: 20).
        step_seconds: simulated seconds per step (thesis: 1).
        physics_hz: physics substeps per second (1/240 s keeps penetration ≈ 7 mm).
        start_distance: ``(min, max)`` start distance from the origin for navigation, m.
        state_weight: weight of ``R(s_t)`` in the per-step reward.
        progress_weight: weight of the progress term in the per-step reward.
        final_weight: weight of the final state's ``R`` in the last step's reward.
        hold_torque: holding torque of a stopped servo beyond back-EMF braking, N·m.
        settle_seconds: simulated time the robot settles at spawn before step 0.
        terrain: Perlin tile parameters for ``nav-terrain``.
        render_mode: ``"rgb_array"`` (current frame) or ``"rgb_array_list"`` (frames at
            ``render_fps`` of simulated time since reset), both headless.
        render_size: frame ``(width, height)`` in pixels.
        free_speed: the servo's free leg speed at full command, rad/s (see module docs).
    """

    metadata = {"render_modes": ["rgb_array", "rgb_array_list"], "render_fps": 10}  # noqa: RUF012 (gymnasium API)

    def __init__(
        self,
        task: str = "nav-flat",
        design: Design | None = None,
        randomization: Randomization | None = None,
        motor_model: MotorModel = "dc",
        stall_torque: float = C.STALL_TORQUE,
        episode_steps: int = 20,
        step_seconds: float = 1.0,
        physics_hz: int = 240,
        start_distance: tuple[float, float] = (0.5, 2.0),
        state_weight: float = 1.0,
        progress_weight: float = 5.0,
        final_weight: float = 0.0,
        hold_torque: float = 0.3,
        settle_seconds: float = 0.5,
        terrain: TerrainConfig | None = None,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (320, 240),
        free_speed: float = C.LEG_SPEED,
    ) -> None:
        super().__init__()
        self.task: TaskSpec = get_task(task)
        _check_servo(motor_model, stall_torque, free_speed)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise SimError(f"render_mode={render_mode!r} must be one of {self.metadata['render_modes']}")
        if episode_steps < 1 or step_seconds <= 0 or physics_hz < 60:
            raise SimError("episode_steps >= 1, step_seconds > 0 and physics_hz >= 60 are required")
        lo, hi = start_distance
        if not 0.0 <= lo <= hi:
            raise SimError(f"start_distance={start_distance} must satisfy 0 <= min <= max")
        self.fixed_design = design
        self.randomization = randomization if randomization is not None else Randomization()
        self.motor_model: MotorModel = motor_model
        self.stall_torque = float(stall_torque)
        self.free_speed = float(free_speed)
        self._damping = self.stall_torque / self.free_speed  # the DC line's slope, N·m·s/rad
        self.episode_steps = episode_steps
        self.physics_hz = physics_hz
        self.substeps = round(step_seconds * physics_hz)
        self.start_distance = (float(lo), float(hi))
        self.state_weight = state_weight
        self.progress_weight = progress_weight
        self.final_weight = final_weight
        self.hold_torque = hold_torque
        self.settle_substeps = round(settle_seconds * physics_hz)
        self.terrain_config = terrain if terrain is not None else TerrainConfig()
        self.render_mode = render_mode
        self.render_size = render_size
        self._frame_interval = max(1, physics_hz // int(self.metadata["render_fps"]))

        self.action_space = spaces.MultiDiscrete([3, 3])
        low = np.array([-_POSITION_LIMIT] * 3 + [-1.0] * 4 + [-1.0] * 2, dtype=np.float32)
        self._obs_low, self._obs_high = low, -low
        self.observation_space = spaces.Box(low=low, high=-low, dtype=np.float32)

        p = pybullet()

        self._p = p
        self._client = p.connect(p.DIRECT)
        self._robot = -1
        self._scene: Scene | None = None
        self.design: Design = design if design is not None else DEFAULT_DESIGN
        self.model: RobotModel | None = None
        self._command = np.zeros(2)
        self._speed = np.full(2, self.free_speed)
        self._step = 0
        self._potential = 0.0
        self._motor_rng = np.random.default_rng(0)
        self._frames: list[np.ndarray] = []
        self._trail: list[tuple[float, float, float]] = []  # the robot's path so far, drawn in frames
        self._substep_count = 0

    # ------------------------------------------------------------------ episode set-up
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        options = options or {}
        key = int(self.np_random.integers(2**63))
        design_ss, world_ss, motor_ss = np.random.SeedSequence(key).spawn(3)
        design_rng = np.random.default_rng(design_ss)
        world_rng = np.random.default_rng(world_ss)
        self._motor_rng = np.random.default_rng(motor_ss)
        rnd = self.randomization

        self.design = self._choose_design(options.get("design"), design_rng)
        draws = _WorldDraws.draw(world_rng, rnd, self.start_distance)
        terrain_rng = np.random.default_rng(world_rng.integers(2**63))

        p, c = self._p, self._client
        p.resetSimulation(physicsClientId=c)
        p.setGravity(0.0, 0.0, -C.GRAVITY, physicsClientId=c)
        p.setPhysicsEngineParameter(fixedTimeStep=1.0 / self.physics_hz, numSubSteps=1,
                                    deterministicOverlappingPairs=1, physicsClientId=c)
        friction = draws.friction
        self._scene = build_scene(c, self.task, terrain_rng, self.terrain_config, friction)

        self.model = RobotModel.from_design(self.design).scaled(
            body_mass=draws.mass_scale, body_inertia=draws.inertia_scale, leg_mass=draws.leg_mass_scale)
        leg_angles = draws.leg_angles if rnd.leg_angles else (0.0, 0.0)
        xy, yaw = draws.start(self.task.start == "ring", rnd.start_pose, options)
        orientation = p.getQuaternionFromEuler([draws.roll if rnd.start_pose else 0.0, 0.0, yaw])
        depth = self._lowest_point(orientation, leg_angles)
        reach = max(self.design.x, self.design.y, self.design.z, self.design.l)
        z = self._scene.ground_height(xy[0], xy[1], reach) + depth + 0.003
        self._robot = build_robot(c, self.model, (xy[0], xy[1], z), orientation, leg_angles, friction)

        self._command = np.zeros(2)
        self._speed = np.full(2, self.free_speed)
        self._frames = []
        self._trail = []
        self._substep_count = 0
        self._set_motors(self._command)
        for _ in range(self.settle_substeps):
            self._substep()
        self._step = 0
        position, _, orientation = self._state()
        self._potential = self.task.potential(position)
        self._capture_frame(force=True)
        info = {"design": self.design.as_tuple(), "step": 0, "spawn_position": (xy[0], xy[1], z),
                "spawn_yaw": yaw, "friction": friction, "leg_angles": leg_angles}
        return self._observation(position, orientation), info

    def _choose_design(self, requested: Any, rng: np.random.Generator) -> Design:
        drawn = Design.sample(rng)  # always drawn, so the other streams never shift
        while self.randomization.tumbling_designs_only and not drawn.can_tumble:
            drawn = Design.sample(rng)  # the design has a stream of its own
        if requested is not None:
            if isinstance(requested, Design):
                return requested
            return Design.from_sequence(list(requested))
        if self.fixed_design is not None:
            return self.fixed_design
        return drawn if self.randomization.design else DEFAULT_DESIGN

    def _lowest_point(self, orientation: tuple[float, ...], leg_angles: tuple[float, float]) -> float:
        """Depth of the robot's lowest point below its centre, for a given pose."""
        assert self.model is not None
        rot = np.array(self._p.getMatrixFromQuaternion(orientation)).reshape(3, 3)
        hx, hy, hz = self.model.half_extents
        corners = np.array([[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        points = np.vstack([corners, np.array(self.model.leg_tips(leg_angles))]) @ rot.T
        return float(-points[:, 2].min())

    # ------------------------------------------------------------------------ stepping
    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._scene is None:
            raise SimError("call reset() before step()")
        act = np.asarray(action).reshape(-1)
        if act.shape != (2,) or not self.action_space.contains(act.astype(np.int64)):
            raise SimError(f"action {action!r} must be two integers in {{0, 1, 2}}")
        new_command = act.astype(float) - 1.0
        rnd = self.randomization
        noise = self._motor_rng.standard_normal(2)
        latency = self._motor_rng.uniform(0.0, 1.0)
        new_speed = np.maximum(self.free_speed + rnd.motor_speed_sigma * noise, 0.0)
        lat_lo, lat_hi = rnd.latency
        delay = min(round((lat_lo + (lat_hi - lat_lo) * latency) * self.physics_hz), self.substeps)

        # The lookups are hoisted out of the loop: it runs 240 times a step, and the calls
        # per substep were a tenth of an evaluation episode.
        step_simulation, set_motors, client = self._p.stepSimulation, self._set_motors, self._client
        every_substep, capture = self.motor_model == "dc", self.render_mode == "rgb_array_list"
        for k in range(self.substeps):
            if k == delay:
                self._command, self._speed = new_command, new_speed
                set_motors(new_command)
            elif every_substep:
                set_motors(self._command)
            if capture:
                self._substep()
            else:
                step_simulation(physicsClientId=client)
        if not capture:
            self._substep_count += self.substeps
        self._step += 1

        position, velocity, orientation = self._state()
        r_state = self.task.state_reward(position, velocity)
        potential = self.task.potential(position)
        progress = potential - self._potential
        self._potential = potential
        truncated = self._step >= self.episode_steps
        reward = self.state_weight * r_state + self.progress_weight * progress
        if truncated:
            reward += self.final_weight * r_state
        info: dict[str, Any] = {
            "R": r_state,
            "reward_state": self.state_weight * r_state,
            "reward_progress": self.progress_weight * progress,
            "distance_to_origin": math.hypot(position[0], position[1]),
            "step": self._step,
            "design": self.design.as_tuple(),
        }
        if truncated:
            info["final_R"] = r_state
            info["final_position"] = position
        return self._observation(position, orientation), float(reward), False, truncated, info

    # ------------------------------------------------- snapshots (planning, analysis)
    def snapshot(self) -> EnvSnapshot:
        """The whole simulation state mid-episode: physics, motor noise stream, command,
        step count. :meth:`restore` goes back to it, so the same future (the same noise
        and latency draws) can be tried with different actions. Free it with
        :meth:`release`; snapshots live in the physics server's memory."""
        if self._scene is None:
            raise SimError("call reset() before snapshot()")
        state_id = self._p.saveState(physicsClientId=self._client)
        return EnvSnapshot(state_id, copy.deepcopy(self._motor_rng.bit_generator.state), self._command.copy(),
                           self._speed.copy(), self._step, self._potential, self._substep_count)

    def restore(self, snap: EnvSnapshot) -> np.ndarray:
        """Return to ``snap`` (of this episode); returns the observation there."""
        self._p.restoreState(stateId=snap.state_id, physicsClientId=self._client)
        self._motor_rng.bit_generator.state = dict(copy.deepcopy(snap.motor_rng_state))
        self._command, self._speed = snap.command.copy(), snap.speed.copy()
        self._step, self._potential, self._substep_count = snap.step, snap.potential, snap.substep_count
        self._set_motors(self._command)  # motor settings are not part of the saved physics state
        position, _, orientation = self._state()
        return self._observation(position, orientation)

    def release(self, snap: EnvSnapshot) -> None:
        self._p.removeState(snap.state_id, physicsClientId=self._client)

    def reseed_motor_noise(self, seed: int | Sequence[int]) -> None:
        """Replace the motor noise and latency still to come by a fresh stream from
        ``seed``: after :meth:`restore`, a planner then tries an action against a future
        drawn anew instead of the episode's own (which it must not see)."""
        self._motor_rng = np.random.default_rng(seed)

    # ------------------------------------------- continuous driving (the digital twin)
    def set_leg_commands(self, right: float, left: float) -> None:
        """Leg commands in [-1, 1] (fractions of full speed), held until changed. The
        digital twin maps the firmware's servo pulses to these; :meth:`step` is the
        discrete, 1 s-per-action interface the policies were trained on."""
        if not (-1.0 <= right <= 1.0 and -1.0 <= left <= 1.0):
            raise SimError(f"leg commands ({right}, {left}) must be within [-1, 1]")
        self._command = np.array([float(right), float(left)])

    def advance(self, substeps: int) -> None:
        """Simulate ``substeps`` physics substeps under the current leg commands; the
        motors' speed noise is redrawn every simulated second, as in :meth:`step`."""
        if self._scene is None:
            raise SimError("call reset() before advance()")
        for _ in range(substeps):
            if self._substep_count % self.substeps == 0:
                noise = self._motor_rng.standard_normal(2)
                self._speed = np.maximum(self.free_speed + self.randomization.motor_speed_sigma * noise, 0.0)
            self._set_motors(self._command)
            self._substep()

    @property
    def client_id(self) -> int:
        """The PyBullet physics client of this environment (for tests and tools that set
        physics up directly, e.g. pin the body; every PyBullet call must pass it)."""
        return int(self._client)

    @property
    def robot_id(self) -> int:
        """The robot's PyBullet body id in :attr:`client_id` (valid after :meth:`reset`)."""
        return self._robot

    def observation(self) -> np.ndarray:
        """The observation of the state now (what :meth:`step` returns at a step's end);
        for callers that drive the legs with :meth:`advance`."""
        if self._scene is None:
            raise SimError("call reset() before observation()")
        position, _, orientation = self._state()
        return self._observation(position, orientation)

    def base_pose(self) -> tuple[tuple[float, float, float], tuple[float, ...]]:
        """World-frame base position (m) and orientation quaternion ``(x, y, z, w)``."""
        position, _, orientation = self._state()
        return position, orientation

    def _substep(self) -> None:
        self._p.stepSimulation(physicsClientId=self._client)
        self._substep_count += 1
        if self.render_mode == "rgb_array_list" and self._substep_count % self._frame_interval == 0:
            self._capture_frame(force=True)

    def _set_motors(self, command: np.ndarray) -> None:
        """Apply the motor model for the current command (see module docs).

        Runs every substep for the DC model: plain floats, no numpy (it was a quarter of
        the step time with 2-element arrays).
        """
        p, c = self._p, self._client
        u0, u1 = float(command[0]), float(command[1])
        t0, t1 = u0 * float(self._speed[0]), u1 * float(self._speed[1])
        if self.motor_model == "dc":
            s0, s1 = p.getJointStates(self._robot, _JOINTS, physicsClientId=c)
            d = self._damping
            f0 = abs(d * (t0 - s0[1])) + (self.hold_torque if u0 == 0.0 else 0.0)
            f1 = abs(d * (t1 - s1[1])) + (self.hold_torque if u1 == 0.0 else 0.0)
        else:  # velocity control capped at the stall torque, holding included
            f0 = f1 = self.stall_torque
        p.setJointMotorControlArray(self._robot, _JOINTS, p.VELOCITY_CONTROL, targetVelocities=(t0, t1),
                                    forces=(f0, f1), physicsClientId=c)

    def _state(self) -> tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, ...]]:
        p, c = self._p, self._client
        pos, orn = p.getBasePositionAndOrientation(self._robot, physicsClientId=c)
        vel, _ = p.getBaseVelocity(self._robot, physicsClientId=c)
        return (pos[0], pos[1], pos[2]), (vel[0], vel[1], vel[2]), tuple(orn)

    def _observation(self, position: tuple[float, ...], orientation: tuple[float, ...]) -> np.ndarray:
        obs = np.array([*position, *orientation, *self._command], dtype=np.float32)
        return np.clip(obs, self._obs_low, self._obs_high)

    # ----------------------------------------------------------------------- rendering
    def _capture_frame(self, force: bool = False) -> None:
        if self.render_mode == "rgb_array_list" and force:
            self._frames.append(self._render_frame())

    def _render_frame(self) -> np.ndarray:
        """The scene, with the floor grid, the goal, the path so far and the step and R
        (:mod:`tumblebot.sim.world.render`); navigation from a fixed camera over the arena."""
        from tumblebot.sim.world import render

        p, c = self._p, self._client
        width, height = self.render_size
        position, velocity, _ = self._state()
        navigation = self.task.start == "ring"
        view = p.computeViewMatrixFromYawPitchRoll(**render.camera_pose(navigation, position))
        proj = p.computeProjectionMatrixFOV(fov=60.0, aspect=width / height, nearVal=0.02, farVal=20.0)
        _, _, rgba, _, _ = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER,
                                            physicsClientId=c)
        image = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3]
        if not self._trail or self._trail[-1] != position:
            self._trail.append(position)
        scene = self._scene
        assert scene is not None
        substep = self._substep_count - self.settle_substeps
        return render.annotate(image, render.Camera(tuple(view), tuple(proj), width, height), navigation=navigation,
                               path=self._trail, ground=lambda x, y: scene.ground_height(x, y, 0.0),
                               step=max(substep, 0) / self.substeps, steps=self.episode_steps,
                               reward=self.task.state_reward(position, velocity))

    def render(self) -> Any:
        if self.render_mode == "rgb_array":
            return self._render_frame()
        if self.render_mode == "rgb_array_list":
            frames, self._frames = self._frames, []
            return frames
        return None

    def close(self) -> None:
        if self._client >= 0:
            self._p.disconnect(physicsClientId=self._client)
            self._client = -1
