"""reports/policy-headroom/setting_features.py: what predicts which goto setting a body prefers."""

import json
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from tests.helpers import load_script
from tumblebot.sim.world.design import tumbling_designs

SCRIPT = Path(__file__).resolve().parents[2] / "reports" / "policy-headroom" / "setting_features.py"


@pytest.fixture(scope="module")
def features() -> ModuleType:
    return load_script(SCRIPT, "setting_features")


def test_that_a_line_in_the_feature_that_made_the_differences_explains_them(features: ModuleType) -> None:
    x = np.linspace(1.0, 2.0, 30)
    r2, loo = features._explained(2.0 * x + 0.1, x[:, None])
    assert r2 == pytest.approx(1.0) and loo == pytest.approx(1.0)
    r2, loo = features._explained(np.random.default_rng(0).normal(size=30), x[:, None])
    assert r2 < 0.2 and loo < 0.1


def test_that_a_threshold_rule_takes_the_setting_where_it_gains(features: ModuleType) -> None:
    x = np.sort(np.random.default_rng(1).uniform(1.0, 2.0, 20))
    y = np.where(x < 1.5, 0.05, -0.02)  # the setting gains on the short side only
    short = int((x < 1.5).sum())
    # every gain, less at most the two designs beside the threshold, which held out may fall on the wrong side
    assert (0.05 * short - 0.05 - 0.02) / 20 - 1e-12 <= features._rule_gain(y, x) <= 0.05 * short / 20 + 1e-12
    assert features._rule_gain(-y, x) >= (0.02 * (20 - short) - 0.07) / 20 - 1e-12  # and on the long side


def test_that_it_reads_a_sweep_and_measures_what_plan_sees(features: ModuleType, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    sweep = tmp_path / "sweep.jsonl"
    sweep.write_text("".join(json.dumps({"design": list(d.as_tuple()), "layout": "tri-plan", "goto": 0.8,
                                         "compared": [3], "means": [0.8], "differences": [0.01 * k],
                                         "errors": [0.01]}) + "\n"
                             for k, d in enumerate(tumbling_designs(4, seed=3))))
    out = tmp_path / "rows.json"
    assert features.main([str(sweep), "--episodes", "2", "--workers", "1", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "4 swept designs" in text and "setting 3 − plan: 4 designs" in text
    rows = json.loads(out.read_text())
    assert [r["differences"]["3"] for r in rows] == pytest.approx([0.0, 0.01, 0.02, 0.03])
    assert all(r["drive"] > 0 and r["reach"] > 1 for r in rows)


def test_that_an_unreadable_sweep_is_one_error_line(features: ModuleType, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.jsonl"
    bad.write_text("{not json}\n")
    assert features.main([str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a sweep record" in err[0]
