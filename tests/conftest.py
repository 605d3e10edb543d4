"""Shared fixtures. PyBullet prints its build time on import; tests do not care."""

from __future__ import annotations

import pytest

from tumblebot.sim.world.design import Design


@pytest.fixture
def xi3_robot() -> Design:
    return Design(0.292, 0.129, 0.098, 0.136)
