"""The JSON files tumblebot writes (study summaries, reports, benchmark results) are strict
JSON whatever numbers they hold: any JSON reader parses them back."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tumblebot import jsonio
from tumblebot.sim.optimize.trials import to_json


def test_that_numpy_numbers_and_unreached_objectives_are_written_as_strict_json() -> None:
    out = {"reference": {"objective": float("-inf"), "design": (np.float64(0.29), 0.13),
                         "scores": np.array([0.5, np.nan])},
           "efficient": [{"episodes": np.int64(120), "p_vs_reference": None, "verdict": "tied", "ok": np.bool_(True)}],
           1: 4}
    for text in (jsonio.dumps(out), to_json(out)):
        assert "Infinity" not in text and "NaN" not in text
        back = json.loads(text, parse_constant=lambda name: pytest.fail(f"{name} is not JSON"))
        assert back["reference"] == {"objective": None, "design": [0.29, 0.13], "scores": [0.5, None]}
        assert back["efficient"] == [{"episodes": 120, "p_vs_reference": None, "verdict": "tied", "ok": True}]
        assert back["1"] == 4


def test_that_what_json_cannot_hold_is_an_error_not_a_file() -> None:
    with pytest.raises(TypeError):
        jsonio.dumps({"when": object()})
