import math

import numpy as np
import pytest
from scipy.integrate import quad

from tumblebot.sim.world import constants as C
from tumblebot.sim.world.design import THESIS_ROBOTS, Design
from tumblebot.sim.world.power import (
    displacement_per_tumble,
    half_tumble_power,
    leg_angle,
    power_breakdown,
    theta_ddot,
    theta_ddot_appendix,
)

TABLE_3_1_E = {"0": 6.05, "1": 6.00, "3": 5.20, "inf": 3.76}


@pytest.mark.parametrize("key", list(TABLE_3_1_E))
def test_that_e_reproduces_thesis_table_3_1_within_one_percent(key: str) -> None:
    e = power_breakdown(THESIS_ROBOTS[key]).e
    assert e == pytest.approx(TABLE_3_1_E[key], rel=0.01)


@pytest.mark.parametrize("key", list(TABLE_3_1_E))
def test_that_implied_masses_are_those_of_a_half_kilo_robot(key: str) -> None:
    assert 0.55 <= power_breakdown(THESIS_ROBOTS[key]).mass <= 0.75


@pytest.mark.parametrize("key", list(TABLE_3_1_E))
@pytest.mark.parametrize("pose", ["flat", "tall"])
def test_that_closed_form_theta_ddot_matches_the_appendix_abc_form_inside_the_range(key: str, pose: str) -> None:
    w = THESIS_ROBOTS[key]
    r = w.pivot_radius
    phi = math.atan2(w.z, w.y) if pose == "flat" else math.atan2(w.y, w.z)
    theta = np.linspace(0.02, math.pi / 2 - phi - 0.02, 25)
    gamma = leg_angle(theta, phi, w.l, r)
    np.testing.assert_allclose(theta_ddot(gamma, w.l, r), theta_ddot_appendix(gamma, w.l, r), rtol=1e-9)


def test_that_the_closed_form_is_finite_where_the_appendix_form_is_singular() -> None:
    w = THESIS_ROBOTS["0"]
    r = w.pivot_radius
    phi = math.atan2(w.z, w.y)
    gamma_end = leg_angle(math.pi / 2 - phi, phi, w.l, r)
    assert np.isfinite(theta_ddot(gamma_end, w.l, r))
    with np.errstate(all="ignore"):
        appendix = theta_ddot_appendix(gamma_end, w.l, r)
    assert not np.isfinite(appendix) or abs(appendix) > 1e6


def test_that_gauss_legendre_integration_agrees_with_adaptive_quadrature() -> None:
    w = THESIS_ROBOTS["3"]
    m, r = 0.7, w.pivot_radius
    phi = math.atan2(w.z, w.y)
    inertia = m * (r * r + (w.y**2 + w.z**2) / 12)

    def integrand(theta: float) -> float:
        g = leg_angle(theta, phi, w.l, r)
        tau = r * m * C.GRAVITY * math.sin(theta + phi + math.pi / 2) - inertia * float(theta_ddot(g, w.l, r))
        return (tau / C.KE) ** 2 * C.WINDING_RESISTANCE + C.LEG_SPEED * tau

    reference, _ = quad(integrand, 0.0, math.pi / 2 - phi, epsabs=1e-12)
    assert half_tumble_power(m, w.y, w.z, w.l, phi) == pytest.approx(reference, rel=1e-9)


def test_that_displacement_uses_the_squared_half_dimensions() -> None:
    y, z = 0.12, 0.16
    r = math.hypot(y / 2, z / 2)
    assert displacement_per_tumble(y, z) == pytest.approx(y + z + (2 * r - y / 2 - z / 2) / C.GROUND_FRICTION)


def test_that_designs_that_cannot_tumble_get_infinite_e_not_nan_or_a_crash() -> None:
    b = power_breakdown(Design(0.2, 0.2, 0.2, 0.07))
    assert not b.can_tumble
    assert b.e == math.inf
    assert b.as_dict()["e"] is None
    assert b.mass > 0


def test_that_e_grows_with_mass() -> None:
    narrow = power_breakdown(Design(0.189, 0.15, 0.12, 0.2)).e
    wide = power_breakdown(Design(0.300, 0.15, 0.12, 0.2)).e
    assert wide > narrow
