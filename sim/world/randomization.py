"""Domain randomisation: what varies between episodes, and how much.

Every draw comes from generators the environment derives from its seed, split into
independent streams so that common random numbers hold: episode ``i`` with seed ``S``
draws the same start, terrain, masses, friction, motor noise and latency whatever the
design is (the design has a stream of its own).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from tumblebot.sim.errors import SimError


@dataclass(frozen=True)
class Randomization:
    """Randomisation settings. Relative sigmas multiply the nominal value by
    ``1 + N(0, σ)`` (clipped to ±3σ).

    Attributes:
        design: when the environment has no fixed design, draw ``w`` uniformly over the
            bounds every episode (one policy then serves every design, as in the thesis).
        tumbling_designs_only: with ``design``, draw uniformly over the designs whose legs
            can tumble the body (``l > r``, 74 % of the bounds) instead: the optimiser never
            runs episodes on the others, and on them no action changes anything.
        mass_rel_sigma: body and leg masses (Schwartzwald et al.: 5 %).
        inertia_rel_sigma: each principal moment of the body.
        friction: nominal lateral friction between robot and ground.
        friction_rel_sigma: relative spread of that friction.
        motor_speed_sigma: per-step, per-motor noise on the free leg speed, rad/s
            (Schwartzwald et al.: 0.8 rad/s).
        latency: command latency range ``(lo, hi)``, seconds, drawn per step.
        leg_angles: start with legs at random angles (the real robot has no encoders).
        start_pose: start on a random one of the four long faces (else flat, z up).
    """

    design: bool = True
    tumbling_designs_only: bool = False
    mass_rel_sigma: float = 0.05
    inertia_rel_sigma: float = 0.05
    friction: float = 0.9
    friction_rel_sigma: float = 0.05
    motor_speed_sigma: float = 0.8
    latency: tuple[float, float] = (0.0, 0.040)
    leg_angles: bool = True
    start_pose: bool = True

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not value >= 0.0:
                raise SimError(f"randomisation {f.name}={value} must be a non-negative number")
        lo, hi = self.latency
        if not 0.0 <= lo <= hi <= 0.5:
            raise SimError(f"randomisation latency={self.latency} must satisfy 0 <= lo <= hi <= 0.5 s")

    @classmethod
    def off(cls) -> Randomization:
        """Nominal everything: for scripted demos and exact comparisons."""
        return cls(design=False, mass_rel_sigma=0.0, inertia_rel_sigma=0.0, friction_rel_sigma=0.0,
                   motor_speed_sigma=0.0, latency=(0.0, 0.0), leg_angles=False, start_pose=False)
