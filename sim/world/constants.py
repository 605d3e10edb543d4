"""Physical constants of the tumbler (thesis Table A.1) and derived motor figures.

All SI units. The servos are modelled as DC gear-motors: with supply voltage ``V`` the
output torque at leg speed ``ω`` is ``τ = ke·(V − ke·ω)/R``. The supply is chosen so that
the free (no-load) speed equals the thesis's leg speed ``γ̇``: ``V = ke·γ̇ ≈ 6.0 V``.
"""

from __future__ import annotations

from tumblebot.defaults import MAX_STALL_TORQUE as MAX_STALL_TORQUE  # re-exported: the servo limit

GRAVITY = 9.81  #: m/s²
LEG_SPEED = 3.67  #: γ̇, free leg speed at full command, rad/s
KE = 1.64  #: back-EMF / torque constant at the output shaft, V·s/rad (= N·m/A)
WINDING_RESISTANCE = 16.96  #: R, Ω
GROUND_FRICTION = 0.645  #: μ used by the power model's sliding term

SUPPLY_VOLTAGE = KE * LEG_SPEED  #: V ≈ 6.02 V, the voltage that gives free speed γ̇
#: Viscous term of the DC model, ke²/R ≈ 0.159 N·m·s/rad.
MOTOR_DAMPING = KE * KE / WINDING_RESISTANCE
#: Stall torque at full command, ke·V/R ≈ 0.582 N·m.
STALL_TORQUE = KE * SUPPLY_VOLTAGE / WINDING_RESISTANCE
