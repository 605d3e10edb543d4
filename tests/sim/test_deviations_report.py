"""reports/policy-headroom/deviations.py: one-step deviations from a policy's own episode."""

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from tests.helpers import load_script

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "reports" / "policy-headroom" / "deviations.py"


@pytest.fixture(scope="module")
def deviations() -> ModuleType:
    return load_script(SCRIPT, "deviations")


def test_that_a_branch_continued_with_the_policys_own_action_replays_its_episode_exactly(
        deviations: ModuleType) -> None:
    """The advantage is only the one action's: restoring the snapshot and the policy's
    memory reproduces the rest of the episode to the last bit."""
    worker = deviations._worker(str(ROOT / "policies" / "nav-flat.onnx"), "nav-flat")
    try:
        for seed in (11, 12):
            final, branches = deviations.drive(worker, seed, {0, 7, 19})
            assert [b.step for b in branches] == [0, 7, 19]
            for branch in branches:
                assert deviations.deviate(worker, branch, branch.own) == final
            final_again, branches = deviations.drive(worker, seed, {5})
            assert final_again == final
            other = (branches[0].own + 1) % len(deviations.ALL_ACTIONS)
            assert np.isfinite(deviations.deviate(worker, branches[0], other))
    finally:
        worker.env.close()


def test_that_the_summary_counts_every_deviation_and_reports_each_class(deviations: ModuleType) -> None:
    rng = np.random.default_rng(0)
    n = 400
    rows = np.column_stack([rng.integers(0, 20, n), np.zeros(n), rng.integers(1, 9, n), rng.normal(-0.02, 0.2, n)])
    summary = deviations.summarise(rows)
    assert summary["deviations"] == n
    assert sum(count for count, _, _ in summary["by_step"].values()) == n
    assert summary["by_own_action"]["RR"][0] == n
    assert summary["overall"][0] == pytest.approx(rows[:, 3].mean())
    assert all(count >= 30 for count, _, _ in summary["by_pair"].values())
    text = deviations.report(summary, 100, np.full(100, 0.5), Path("p.onnx"))
    assert "100 episodes (mean final R 0.500), 400 one-step deviations" in text and "RR->" in text


def test_that_the_cross_fit_finds_a_class_that_gains_and_scores_noise_at_zero(deviations: ModuleType) -> None:
    rng = np.random.default_rng(1)
    n = 8000
    rows = np.column_stack([rng.integers(0, 20, n), rng.integers(0, 3, n), rng.integers(3, 9, n),
                            rng.normal(-0.02, 0.2, n)])
    halves = rng.integers(0, 2, n)
    noise = deviations.cross_fit(rows, halves)
    assert noise["held_out"][0] < 2 * noise["held_out"][1]  # nothing real to find
    planted = (rows[:, 0] >= 7) & (rows[:, 0] < 14) & (rows[:, 1] == 0) & (rows[:, 2] == 4)
    rows[planted, 3] += 0.3
    found = deviations.cross_fit(rows, halves)
    assert found["held_out"][0] > 3 * found["held_out"][1] > 0


def test_that_the_halves_split_episodes_by_their_design_whatever_the_order(deviations: ModuleType) -> None:
    from tumblebot.sim.control.features import DESIGN

    inputs = np.zeros((12, 32), dtype=np.float32)
    designs = np.repeat(np.arange(6)[:, None] * 0.1 + np.array([[0.2, 0.1, 0.1, 0.15]]), 2, axis=0)
    inputs[:, DESIGN] = designs
    halves = deviations.episode_halves(inputs)
    assert list(halves) == [0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1, 1]
    order = np.random.default_rng(0).permutation(12)
    assert list(deviations.episode_halves(inputs[order])) == list(halves[order])


def test_that_a_saved_file_reads_back_and_any_other_file_gets_one_error_line(
        deviations: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    saved = tmp_path / "d.npz"
    rng = np.random.default_rng(2)
    inputs = rng.normal(size=(16, 32)).astype(np.float32)
    np.savez_compressed(saved, inputs=inputs, step=np.arange(16) % 20, own=np.zeros(16, int),
                        other=np.ones(16, int), advantage=np.linspace(-0.1, 0.1, 16), finals=np.full(2, 0.5))
    rows, back, finals = deviations.load(saved)
    assert np.array_equal(back, inputs) and rows.shape == (16, 4) and list(finals) == [0.5, 0.5]
    assert np.allclose(rows[:, 3], np.linspace(-0.1, 0.1, 16))
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    (tmp_path / "text.npz").write_bytes(b"not numpy at all")
    for name in ("text.npz", "other.npz", "missing.npz"):
        assert deviations.main(["--from", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("deviations: ") and len(err.splitlines()) == 1 and name in err
