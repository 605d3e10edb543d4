"""The thesis's power model: estimated electrical energy per metre, ``e(w)`` in W/m.

Thesis §2.5 and Appendix A, with these corrections:

* Per motor ``P = (τ/ke)²·R + γ̇·τ``, modelled as a single motor carrying all the torque.
* Torque about the pivot corner ``τ(θ) = r·m·g·sin(θ + φ + π/2) − I·θ̈`` with
  ``r = sqrt((y/2)² + (z/2)²)``, ``I = m·(r² + (y² + z²)/12)``.
* Leg angle ``γ = π − asin(r·sin(θ + φ)/l) − θ − φ``, ``b² = l² + r² − 2·l·r·cos γ``.
* ``θ̈ = γ̇²·l·r·sin γ·(l² − r²)/b⁴`` (:func:`theta_ddot`), an equivalent closed form of
  the appendix's A/B/C expression (:func:`theta_ddot_appendix`) without its removable
  singularity at ``θ + φ = π/2``. The appendix prints ``Ċ = 2ℓrγ̇ sin γ cos γ v^(-3/2) − …``;
  differentiating its own ``C`` gives ``2ℓ²rγ̇ …``, which is what is implemented (the
  tests check both forms agree).
* ``P`` integrates the instantaneous power **over θ, not over time**, from 0 to
  ``π/2 − φ``, once in the flat pose (``φ = atan2(z, y)``) and once in the tall pose
  (``φ = atan2(y, z)``), and sums the two. This reproduces the thesis as written; the
  result is a "power" in W·rad, not an energy in J.
* Displacement per 180° tumble ``d = y + z + (2r − y/2 − z/2)/μ`` (the thesis drops the
  squares under the root), and ``e = P/d``.

Designs whose legs cannot lift the body past its balance point (``l ≤ r``) cannot tumble
under this model: :func:`power_breakdown` marks them ``can_tumble=False`` with
``e = +inf`` (so any ``f = R/(e+1)^ξ`` with ``ξ > 0`` is 0 and ``ξ = ∞`` ranks them last).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tumblebot.sim.world import constants as C
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.mass import DEFAULT_MASS_MODEL, MassModel

#: Gauss–Legendre nodes used for the θ integrals (the integrand is smooth).
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(64)


def leg_angle(theta: np.ndarray | float, phi: float, l: float, r: float) -> np.ndarray:  # noqa: E741
    """``γ(θ)``: the leg angle at body rotation ``θ`` (thesis Appendix A)."""
    psi = np.asarray(theta, dtype=float) + phi
    return np.pi - np.arcsin(np.clip(r * np.sin(psi) / l, -1.0, 1.0)) - psi


def theta_ddot(gamma: np.ndarray | float, l: float, r: float, gamma_dot: float = C.LEG_SPEED) -> np.ndarray:  # noqa: E741
    """Closed-form angular acceleration of the body, ``γ̇²·l·r·sin γ·(l² − r²)/b⁴``.

    Derived from ``θ + φ = atan2(l·sin γ, r − l·cos γ)`` with ``γ̈ = 0``.
    """
    g = np.asarray(gamma, dtype=float)
    b2 = l * l + r * r - 2.0 * l * r * np.cos(g)
    return np.asarray(gamma_dot**2 * l * r * np.sin(g) * (l * l - r * r) / (b2 * b2))


def theta_ddot_appendix(
    gamma: np.ndarray | float, l: float, r: float, gamma_dot: float = C.LEG_SPEED  # noqa: E741
) -> np.ndarray:
    """The appendix's A/B/C form of ``θ̈`` (singular where ``l·sin γ = b``).

    Kept to test the closed form against (they agree wherever both are defined).
    """
    g = np.asarray(gamma, dtype=float)
    s, c = np.sin(g), np.cos(g)
    v = l * l + r * r - 2.0 * l * r * c
    a_inner = 1.0 - l * l * s * s / v
    a = a_inner**-0.5
    b = l * c * v**-0.5
    cc = l * l * r * s * s * v**-1.5
    a_dot = gamma_dot * a_inner**-1.5 * (v * (l * l * s * c) - l**3 * r * s**3) / v**2
    b_dot = -l * gamma_dot * s * v**-0.5 - l * l * r * gamma_dot * s * c * v**-1.5
    c_dot = 2 * l * l * r * gamma_dot * s * c * v**-1.5 - 3 * l**3 * r * r * gamma_dot * s**3 * v**-2.5
    return np.asarray(a * (b_dot - c_dot) * gamma_dot + a_dot * (b - cc) * gamma_dot)


def half_tumble_power(
    mass: float, y: float, z: float, l: float, phi: float, gamma_dot: float = C.LEG_SPEED  # noqa: E741
) -> float:
    """``∫₀^{π/2−φ} (τ(θ)/ke)²·R + γ̇·τ(θ) dθ`` for one starting pose (angle ``φ``)."""
    r = math.hypot(y / 2, z / 2)
    inertia = mass * (r * r + (y * y + z * z) / 12.0)
    upper = math.pi / 2 - phi
    theta = 0.5 * upper * (_GL_NODES + 1.0)
    gamma = leg_angle(theta, phi, l, r)
    tau = r * mass * C.GRAVITY * np.sin(theta + phi + np.pi / 2) - inertia * theta_ddot(gamma, l, r, gamma_dot)
    integrand = (tau / C.KE) ** 2 * C.WINDING_RESISTANCE + gamma_dot * tau
    return float(0.5 * upper * np.dot(_GL_WEIGHTS, integrand))


def displacement_per_tumble(y: float, z: float, mu: float = C.GROUND_FRICTION) -> float:
    """``d``: distance covered by a 180° tumble including the slide, metres."""
    r = math.hypot(y / 2, z / 2)
    return y + z + (2 * r - y / 2 - z / 2) / mu


@dataclass(frozen=True)
class PowerBreakdown:
    """Everything the power model computes for one design (SI units)."""

    design: Design
    mass: float  #: m(w), kg
    can_tumble: bool  #: l > r
    flat_term: float  #: half-tumble integral from the flat pose, W·rad (NaN if not tumbling)
    tall_term: float  #: half-tumble integral from the tall pose, W·rad (NaN if not tumbling)
    power: float  #: flat + tall
    displacement: float  #: d, m
    e: float  #: P/d, "W/m"; +inf when the design cannot tumble

    def as_dict(self) -> dict[str, object]:
        """JSON-ready: non-finite numbers become ``None``."""

        def clean(v: float) -> float | None:
            return v if math.isfinite(v) else None

        return {
            "design": self.design.as_dict(),
            "mass": self.mass,
            "can_tumble": self.can_tumble,
            "flat_term": clean(self.flat_term),
            "tall_term": clean(self.tall_term),
            "power": clean(self.power),
            "displacement": self.displacement,
            "e": clean(self.e),
        }


def power_breakdown(w: Design, mass_model: MassModel = DEFAULT_MASS_MODEL) -> PowerBreakdown:
    """Evaluate the full power model for design ``w``."""
    m = mass_model.total_mass(w)
    d = displacement_per_tumble(w.y, w.z)
    if not w.l > w.pivot_radius:
        nan = float("nan")
        return PowerBreakdown(w, m, False, nan, nan, nan, d, math.inf)
    flat = half_tumble_power(m, w.y, w.z, w.l, math.atan2(w.z, w.y))
    tall = half_tumble_power(m, w.y, w.z, w.l, math.atan2(w.y, w.z))
    return PowerBreakdown(w, m, True, flat, tall, flat + tall, d, (flat + tall) / d)


def energy_per_metre(w: Design, mass_model: MassModel = DEFAULT_MASS_MODEL) -> float:
    """``e(w)`` in W/m (``+inf`` for designs that cannot tumble)."""
    return power_breakdown(w, mass_model).e
