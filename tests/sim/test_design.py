import math
from typing import Any

import numpy as np
import pytest

from tumblebot.sim.errors import DesignError
from tumblebot.sim.world.design import BOUNDS, PARAMETERS, Design


@pytest.mark.parametrize("name", PARAMETERS)
def test_that_nan_in_any_parameter_is_rejected_by_name(name: str) -> None:
    values: dict[str, Any] = dict(x=0.25, y=0.15, z=0.12, l=0.2)
    values[name] = math.nan
    with pytest.raises(DesignError, match=f"{name}=nan"):
        Design(**values)


@pytest.mark.parametrize("bad", [0.0, -0.1, math.inf])
def test_that_non_positive_or_infinite_values_are_rejected(bad: float) -> None:
    with pytest.raises(DesignError, match="l="):
        Design(0.25, 0.15, 0.12, bad, allow_out_of_bounds=True)


@pytest.mark.parametrize("name", PARAMETERS)
def test_that_out_of_bounds_values_name_the_parameter_and_the_bound(name: str) -> None:
    values: dict[str, Any] = dict(x=0.25, y=0.15, z=0.12, l=0.2)
    lo, hi = BOUNDS[name]
    values[name] = hi + 0.01
    with pytest.raises(DesignError, match=rf"{name}=.*\[{lo}, {hi}\]"):
        Design(**values)


def test_that_out_of_bounds_designs_are_accepted_with_the_explicit_opt_in() -> None:
    w = Design(0.393, 0.117, 0.158, 0.218, allow_out_of_bounds=True)
    assert w.x == pytest.approx(0.393)
    assert not w.in_bounds()


def test_that_parse_reads_comma_separated_metres_and_rejects_garbage() -> None:
    assert Design.parse("0.292, 0.129,0.098,0.136").as_tuple() == (0.292, 0.129, 0.098, 0.136)
    with pytest.raises(DesignError, match="four comma-separated"):
        Design.parse("0.2,0.1,0.1")
    with pytest.raises(DesignError, match="z='abc'"):
        Design.parse("0.2,0.12,abc,0.1")


def test_that_sampled_designs_lie_inside_the_bounds() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        assert Design.sample(rng).in_bounds()


def test_that_a_design_cannot_tumble_when_its_leg_is_shorter_than_the_pivot_radius() -> None:
    assert not Design(0.2, 0.2, 0.2, 0.07).can_tumble
    assert Design(0.292, 0.129, 0.098, 0.136).can_tumble


def test_that_the_xi3_robot_is_written_once() -> None:
    from tumblebot.defaults import XI3_ROBOT, XI3_ROBOT_TEXT
    from tumblebot.sim.world.design import THESIS_ROBOTS
    from tumblebot.sim.world.env import DEFAULT_DESIGN

    assert THESIS_ROBOTS["3"].as_tuple() == XI3_ROBOT == DEFAULT_DESIGN.as_tuple()
    assert Design.parse(XI3_ROBOT_TEXT).as_tuple() == XI3_ROBOT
    assert THESIS_ROBOTS["3"].as_dict() == {"x": 0.292, "y": 0.129, "z": 0.098, "l": 0.136}
