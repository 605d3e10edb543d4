"""A physics profile: everything the simulator assumes about the world outside the design.

The servo (its model, free speed, stall torque and holding torque), the floor (friction and
its spread between episodes), the radio (command latency) and the motors' speed noise.
One typed, validated JSON file with flat keys in SI units::

    {"name": "lab-a", "motor_model": "dc", "free_speed": 3.67, "stall_torque": 0.582,
     "hold_torque": 0.3, "friction": 0.9, "friction_rel_sigma": 0.05,
     "latency": [0.0, 0.04], "motor_speed_sigma": 0.8}

``thesis`` is the built-in profile (the thesis's servo constants, :data:`THESIS`); a servo
of the catalogue (``sim/world/servos.json``) gives the servo keys
(:meth:`PhysicsProfile.with_servo`). A profile is identified by its :meth:`digest` (its
values, not its name), which studies, model cards and twin records store next to it.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tumblebot.sim.errors import SimError
from tumblebot.sim.world import constants as C
from tumblebot.sim.world.catalogue import servo
from tumblebot.sim.world.randomization import Randomization

if TYPE_CHECKING:
    from tumblebot.sim.world.env import TumblerEnv

MAX_FREE_SPEED = 50.0  #: rad/s; beyond any hobby servo's output shaft
MAX_HOLD_TORQUE = 10.0  #: N·m
MAX_FRICTION = 3.0
MAX_MOTOR_SPEED_SIGMA = 10.0  #: rad/s
MAX_LATENCY = 0.5  #: s


class PhysicsError(SimError):
    """A profile that is missing, malformed or out of range (one line)."""


@dataclass(frozen=True)
class PhysicsProfile:
    """The world outside the design (see the module docs for the file format)."""

    name: str = "thesis"
    motor_model: str = "dc"  #: ``"dc"`` (torque falls with speed) or ``"velocity"`` (speed-controlled)
    free_speed: float = C.LEG_SPEED  #: rad/s, the leg's speed at full command with no load
    stall_torque: float = C.STALL_TORQUE  #: N·m at full command and zero speed
    hold_torque: float = 0.3  #: N·m a stopped servo holds beyond back-EMF braking
    friction: float = 0.9  #: lateral friction coefficient, robot on floor
    friction_rel_sigma: float = 0.05  #: its relative spread between episodes
    latency: tuple[float, float] = (0.0, 0.040)  #: s, command latency drawn per step in [lo, hi]
    motor_speed_sigma: float = 0.8  #: rad/s, per-step noise on each motor's free speed

    def __post_init__(self) -> None:
        def bad(key: str, why: str) -> PhysicsError:
            return PhysicsError(f"physics profile {self.name!r}: {key} {why}")

        if not isinstance(self.name, str) or not self.name.strip():
            raise PhysicsError("a physics profile needs a non-empty name")
        if self.motor_model not in ("dc", "velocity"):
            raise bad("motor_model", f"{self.motor_model!r} must be 'dc' or 'velocity'")
        ranges = {"free_speed": (0.0, MAX_FREE_SPEED, False), "stall_torque": (0.0, C.MAX_STALL_TORQUE, False),
                  "hold_torque": (0.0, MAX_HOLD_TORQUE, True), "friction": (0.0, MAX_FRICTION, False),
                  "friction_rel_sigma": (0.0, 1.0, True), "motor_speed_sigma": (0.0, MAX_MOTOR_SPEED_SIGMA, True)}
        for key, (lo, hi, closed) in ranges.items():
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or not (lo <= value if closed else lo < value) or value > hi:
                raise bad(key, f"{value!r} must be a number in {'[' if closed else '('}{lo:g}, {hi:g}]")
        lat = self.latency
        if not (isinstance(lat, tuple) and len(lat) == 2 and all(isinstance(v, (int, float)) and not
                                                                  isinstance(v, bool) and math.isfinite(v)
                                                                  for v in lat)
                and 0.0 <= lat[0] <= lat[1] <= MAX_LATENCY):
            raise bad("latency", f"{list(lat) if isinstance(lat, tuple) else lat!r} must be [lo, hi] seconds with "
                                 f"0 <= lo <= hi <= {MAX_LATENCY:g}")

    # ------------------------------------------------------------------ files
    @classmethod
    def from_json(cls, data: Any, where: str = "physics profile") -> PhysicsProfile:
        """A profile from a parsed JSON object: unknown keys are errors, missing ones take
        the ``thesis`` value (so a lab can write only what it measured)."""
        if not isinstance(data, dict):
            raise PhysicsError(f"{where}: must be a JSON object")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise PhysicsError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")
        values = {**{k: v for k, v in THESIS.to_json().items() if k != "name"}, **data}
        if isinstance(values["latency"], list):
            values["latency"] = tuple(values["latency"])
        values.setdefault("name", Path(where).stem if where.endswith(".json") else "unnamed")
        try:
            return cls(**values)
        except TypeError as exc:  # e.g. a name that is not a string
            raise PhysicsError(f"{where}: {exc}") from None

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["latency"] = list(self.latency)
        return out

    def write(self, path: Path) -> None:
        path.write_text(json.dumps(self.to_json(), indent=2) + "\n")

    def digest(self) -> str:
        """A hash of the values (not the name): two profiles that simulate alike share it."""
        values = {k: v for k, v in self.to_json().items() if k != "name"}
        return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:16]

    @classmethod
    def load(cls, spec: str) -> PhysicsProfile:
        """A built-in profile by name (``thesis``) or a JSON file."""
        if spec in BUILTIN:
            return BUILTIN[spec]
        path = Path(spec)
        if not path.is_file():
            raise PhysicsError(f"physics profile {spec!r}: not a built-in one ({', '.join(BUILTIN)}) and no such file")
        try:
            data = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise PhysicsError(f"physics profile {spec}: not readable JSON ({exc})") from None
        return cls.from_json(data, str(path))

    # ------------------------------------------------------------------ records
    @classmethod
    def of(cls, model: str | None, stall_torque: float | None, base: PhysicsProfile | None = None) -> PhysicsProfile:
        """``base`` (default ``thesis``) with the ``--motor-model``/``--stall-torque``
        shorthands applied, where given."""
        base = base or THESIS
        changed = replace(base, motor_model=model or base.motor_model,
                          stall_torque=base.stall_torque if stall_torque is None else stall_torque)
        if changed.digest() == base.digest():
            return base
        return replace(changed, name=f"{base.name}, {changed.motor_model} {changed.stall_torque:.3g} N·m")

    @classmethod
    def from_arguments(cls, physics: str | None, model: str | None, stall_torque: float | None) -> PhysicsProfile:
        """The profile of ``--physics`` (default ``thesis``) with the ``--motor-model`` and
        ``--stall-torque`` shorthands applied: what every command that runs episodes takes."""
        return cls.of(model, stall_torque, cls.load(physics) if physics is not None else THESIS)

    @classmethod
    def from_card(cls, data: dict[str, Any]) -> PhysicsProfile:
        """What a model card, study, twin record or report stored: a whole profile (with
        its digest), or, from before profiles, only ``{"motor_model", "stall_torque"}``."""
        if not set(data) - {"motor_model", "stall_torque"}:
            return cls.of(data.get("motor_model"), data.get("stall_torque"))
        return cls.from_json({k: v for k, v in data.items() if k != "digest"}, "stored physics profile")

    def as_fields(self) -> dict[str, Any]:
        """What a study or training config stores of it: the servo shorthands, and the whole
        profile only when it differs from ``thesis`` in more than those (so records of the
        thesis's world read as they did before profiles existed)."""
        beyond_servo = not PhysicsProfile.of(self.motor_model, self.stall_torque).same_as(self)
        return {"motor_model": self.motor_model, "stall_torque": self.stall_torque,
                "physics": self.record() if beyond_servo else None}

    @classmethod
    def of_fields(cls, motor_model: str, stall_torque: float, physics: dict[str, Any] | None) -> PhysicsProfile:
        """The inverse of :meth:`as_fields`."""
        return cls.from_card(physics) if physics is not None else cls.of(motor_model, stall_torque)

    def record(self) -> dict[str, Any]:
        """What records store: every value, and the digest."""
        return {**self.to_json(), "digest": self.digest()}

    @property
    def model(self) -> str:
        """The servo model (``motor_model``)."""
        return self.motor_model

    def same_as(self, other: PhysicsProfile) -> bool:
        return self.digest() == other.digest()

    # ------------------------------------------------------------------ use
    def with_servo(self, name: str) -> PhysicsProfile:
        """This profile with a catalogue servo's free speed and stall torque."""
        spec = servo(name)
        return replace(self, name=f"{self.name}+{name}", free_speed=spec.free_speed, stall_torque=spec.stall_torque)

    def env_kwargs(self) -> dict[str, Any]:
        """The :class:`~tumblebot.sim.world.env.TumblerEnv` keyword arguments of the servo."""
        return {"motor_model": self.motor_model, "stall_torque": self.stall_torque, "free_speed": self.free_speed,
                "hold_torque": self.hold_torque}

    def make_env(self, task: str, **kwargs: Any) -> TumblerEnv:
        """A ``task`` environment under this profile (its servo, floor, radio and motor
        noise) whose design is not drawn: each episode's comes with ``reset`` or a fixed
        ``design`` in ``kwargs`` (passed on to :class:`~tumblebot.sim.world.env.TumblerEnv`
        with the rest). What evaluation, sweeps, calibration and the twin run episodes in."""
        from tumblebot.sim.world.env import TumblerEnv  # pybullet only where an environment is built

        return TumblerEnv(task=task, randomization=self.randomization(Randomization(design=False)),
                          **self.env_kwargs(), **kwargs)

    def randomization(self, base: Randomization) -> Randomization:
        """``base`` with this profile's floor, radio and motor noise."""
        return replace(base, friction=self.friction, friction_rel_sigma=self.friction_rel_sigma,
                       latency=self.latency, motor_speed_sigma=self.motor_speed_sigma)

    def nominal(self) -> Randomization:
        """Nothing drawn: masses, floor, radio and motors at their nominal values, on this
        profile's floor (scripted demos and exact comparisons)."""
        return replace(Randomization.off(), friction=self.friction)

    def describe(self) -> str:
        if replace(self, name=THESIS.name, motor_model=THESIS.motor_model,
                   stall_torque=THESIS.stall_torque).digest() == THESIS.digest():
            return f"{self.motor_model} servo, stall torque {self.stall_torque:.3g} N·m"  # the thesis's world otherwise
        return (f"{self.name}: {self.motor_model} servo, free speed {self.free_speed:.3g} rad/s, stall torque "
                f"{self.stall_torque:.3g} N·m, hold {self.hold_torque:.3g} N·m; friction {self.friction:.3g} "
                f"(±{self.friction_rel_sigma:.0%}); latency {1e3 * self.latency[0]:.0f}–{1e3 * self.latency[1]:.0f} "
                f"ms; motor noise {self.motor_speed_sigma:.3g} rad/s")


THESIS = PhysicsProfile()  #: the thesis's world: its servo constants, floor and radio
BUILTIN: dict[str, PhysicsProfile] = {"thesis": THESIS}


def profile_from_args(args: Any) -> PhysicsProfile:
    """The profile a command's ``--physics``, ``--motor-model`` and ``--stall-torque`` ask for
    (parsed arguments with those three attributes; ``None`` where not given)."""
    return PhysicsProfile.from_arguments(args.physics, args.motor_model, args.stall_torque)
