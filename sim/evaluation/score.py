"""The thesis's objective (§2.2, §2.5): wrapping episode rewards with the energy penalty.

Per task ``f(R, w) = R / (e(w) + 1)^ξ``; the design objective is the batch mean of
``Σ_i λ_i·f_i``. ``ξ = ∞`` means "minimise ``e(w)`` alone", expressed as ``f = −e``.

Caution: for ``R < 0`` the thesis form *rewards* a larger ``e`` (dividing a
negative number by a larger one brings it toward 0). ``variant="monotone"`` multiplies
instead when ``R < 0``, so ``f`` always falls as ``e`` rises. ``"thesis"`` is the default;
results say which one they used.
"""

from __future__ import annotations

import math
from typing import Literal

from tumblebot.sim.errors import SimError

Variant = Literal["thesis", "monotone"]
VARIANTS: tuple[str, ...] = ("thesis", "monotone")


def wrap_reward(R: float, e: float, xi: float, variant: Variant = "thesis") -> float:
    """``f(R, w)`` for episode reward ``R``, energy ``e`` (W/m, may be +inf) and ``ξ ≥ 0``.

    Designs that cannot tumble (``e = +inf``) get ``f = 0`` for finite ``ξ > 0`` under the
    thesis form, ``−inf`` under the monotone form when ``R < 0``, and ``−inf`` for ``ξ = ∞``.
    """
    if variant not in VARIANTS:
        raise SimError(f"wrapper variant {variant!r} must be one of {VARIANTS}")
    if math.isnan(xi) or xi < 0:
        raise SimError(f"ξ={xi} must be a non-negative number or inf")
    if math.isnan(e) or e < 0:
        raise SimError(f"e={e} must be a non-negative number or inf")
    if math.isinf(xi):
        return -e
    if xi == 0:
        return R
    scale = float((e + 1.0) ** xi)
    if variant == "monotone" and R < 0:
        return R * scale
    return R / scale
