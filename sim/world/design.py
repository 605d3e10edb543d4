"""The design vector ``w = (x, y, z, l)`` of a tumbling robot, in metres.

``x`` is the body width along the legs' shared rotation axis (between the two side
plates), ``y`` and ``z`` are the side-profile dimensions, ``l`` is the leg length.
A :class:`Design` is frozen and validated on construction; it is the one type that flows
from the optimiser into the environment, the power model and the URDF writer.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from tumblebot.defaults import XI3_ROBOT
from tumblebot.sim.errors import DesignError

PARAMETERS: tuple[str, ...] = ("x", "y", "z", "l")

#: Optimisation bounds from the thesis (§2.6), metres, inclusive.
BOUNDS: dict[str, tuple[float, float]] = {
    "x": (0.189, 0.300),
    "y": (0.102, 0.250),
    "z": (0.084, 0.200),
    "l": (0.066, 0.250),
}


@dataclass(frozen=True)
class Design:
    """A validated robot design, all lengths in metres.

    Args:
        x: body width along the leg axis (distance between the side plates).
        y: side-profile dimension (horizontal when the robot lies flat).
        z: side-profile dimension (vertical when the robot lies flat).
        l: leg length, from the rotation axis to the foot.
        allow_out_of_bounds: accept values outside :data:`BOUNDS` (still finite and
            positive). The sensitivity analysis of thesis Table 3.2 needs this.

    Raises:
        DesignError: a value is NaN, infinite, non-positive, or outside its bound
            without ``allow_out_of_bounds``. The message names the parameter and bound.
    """

    x: float
    y: float
    z: float
    l: float  # noqa: E741 - the thesis's name for the leg length
    allow_out_of_bounds: bool = False

    def __post_init__(self) -> None:
        for name in PARAMETERS:
            raw = getattr(self, name)
            try:
                value = float(raw)
            except (TypeError, ValueError):
                raise DesignError(f"design parameter {name}={raw!r} is not a number") from None
            if not math.isfinite(value):
                raise DesignError(f"design parameter {name}={value} is not finite")
            if value <= 0.0:
                raise DesignError(f"design parameter {name}={value} m must be positive")
            lo, hi = BOUNDS[name]
            if not self.allow_out_of_bounds and not lo <= value <= hi:
                raise DesignError(
                    f"design parameter {name}={value} m is outside its bound "
                    f"[{lo}, {hi}] m (pass --allow-out-of-bounds on the command line, or "
                    "allow_out_of_bounds=True in Python, to accept it)"
                )
            object.__setattr__(self, name, value)

    @classmethod
    def from_sequence(cls, values: Sequence[float], *, allow_out_of_bounds: bool = False) -> Design:
        """Build a design from ``(x, y, z, l)``."""
        if len(values) != 4:
            raise DesignError(f"a design needs 4 values (x, y, z, l), got {len(values)}")
        x, y, z, l = values  # noqa: E741
        return cls(x, y, z, l, allow_out_of_bounds=allow_out_of_bounds)

    @classmethod
    def parse(cls, text: str, *, allow_out_of_bounds: bool = False) -> Design:
        """Parse ``"x,y,z,l"`` (metres), as typed on a command line."""
        parts = [p.strip() for p in text.split(",")]
        if len(parts) != 4 or any(not p for p in parts):
            raise DesignError(f"design {text!r} must be four comma-separated numbers x,y,z,l")
        values: list[float] = []
        for name, part in zip(PARAMETERS, parts, strict=True):
            try:
                values.append(float(part))
            except ValueError:
                raise DesignError(f"design parameter {name}={part!r} is not a number") from None
        return cls.from_sequence(values, allow_out_of_bounds=allow_out_of_bounds)

    @classmethod
    def sample(cls, rng: np.random.Generator) -> Design:
        """A design drawn uniformly from :data:`BOUNDS` (four draws from ``rng``)."""
        lo = np.array([BOUNDS[n][0] for n in PARAMETERS])
        hi = np.array([BOUNDS[n][1] for n in PARAMETERS])
        return cls.from_sequence(rng.uniform(lo, hi).tolist())

    def as_dict(self) -> dict[str, float]:
        """``{"x": …, "y": …, "z": …, "l": …}`` (metres), as JSON outputs record a design."""
        return dict(zip(PARAMETERS, self.as_tuple(), strict=True))

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.x, self.y, self.z, self.l)

    def __iter__(self) -> Iterator[float]:
        return iter(self.as_tuple())

    def in_bounds(self) -> bool:
        return all(BOUNDS[n][0] <= getattr(self, n) <= BOUNDS[n][1] for n in PARAMETERS)

    @property
    def pivot_radius(self) -> float:
        """``r``: distance from a body edge (the pivot corner) to the leg axis, metres."""
        return math.hypot(self.y / 2.0, self.z / 2.0)

    @property
    def reach(self) -> float:
        """``l / r``: how many pivot radii the legs reach (1 where they just tumble the body;
        the hand-written navigators' best setting depends on it)."""
        return self.l / self.pivot_radius

    @property
    def can_tumble(self) -> bool:
        """Whether a leg is long enough to lift the body past its balance point (``l >= r``)."""
        return self.l >= self.pivot_radius

    def __str__(self) -> str:
        return f"Design(x={self.x:.3f}, y={self.y:.3f}, z={self.z:.3f}, l={self.l:.3f})"


MAX_DRAWS = 1_000_000  #: draws :func:`tumbling_designs` makes before it gives up on its reach bounds


def tumbling_designs(count: int, seed: int, reach_below: float | None = None,
                     reach_above: float | None = None) -> list[Design]:
    """``count`` designs drawn uniformly from the bounds with ``seed``, keeping those whose
    legs can lift the body (:attr:`Design.can_tumble`), in the order drawn; with
    ``reach_below`` (``reach_above``), only those whose legs reach less (at least) that many
    pivot radii (``l / r``; the same draws, filtered)."""
    for name, bound in (("reach_below", reach_below), ("reach_above", reach_above)):
        if bound is not None and bound <= 1.0:
            raise ValueError(f"{name}={bound} must exceed 1 (shorter legs cannot tumble the body)")
    if reach_below is not None and reach_above is not None and reach_above >= reach_below:
        raise ValueError(f"reach_above={reach_above} must be below reach_below={reach_below}: no design has both")
    rng = np.random.default_rng(seed)
    out: list[Design] = []
    draws = 0
    while len(out) < count:
        if draws == MAX_DRAWS:
            named = ((f"below {reach_below}", reach_below), (f"at least {reach_above}", reach_above))
            bounds = " and ".join(text for text, bound in named if bound is not None)
            raise ValueError(f"only {len(out)} of {count} designs in {MAX_DRAWS} draws can tumble and reach "
                             f"{bounds} pivot radii: too few designs in the bounds qualify")
        draws += 1
        design = Design.sample(rng)
        if (design.can_tumble and (reach_below is None or design.reach < reach_below)
                and (reach_above is None or design.reach >= reach_above)):
            out.append(design)
    return out


#: The thesis's robots (Table 3.1), keyed by the ξ they were optimised for.
THESIS_ROBOTS: dict[str, Design] = {
    "0": Design(0.293, 0.117, 0.158, 0.218),
    "1": Design(0.285, 0.117, 0.158, 0.218),
    "3": Design(*XI3_ROBOT),
    "inf": Design(0.189, 0.104, 0.098, 0.152),
}
