"""reports/policy-headroom/self_critical.py: the policy gradient on one-step deviations."""

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import torch

from tests.helpers import load_script

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "reports" / "policy-headroom" / "self_critical.py"
RUN = ROOT / "training" / "checkpoints" / "tri-nav-flat"


@pytest.fixture(scope="module")
def self_critical() -> ModuleType:
    return load_script(SCRIPT, "self_critical")


@pytest.fixture(scope="module")
def worker(self_critical: ModuleType) -> object:
    return self_critical._worker(str(RUN))


def test_that_a_group_scores_each_deviation_against_the_students_own_episode(
        self_critical: ModuleType, worker: object, tmp_path: Path) -> None:
    weights = tmp_path / "w.pt"
    torch.save(worker.policy.state_dict(), weights)  # type: ignore[attr-defined]
    seed, final, samples = self_critical.group(worker, (21, 0, str(weights), 3, 4.0))
    again = self_critical.group(worker, (21, 0, str(weights), 0, 4.0))
    assert seed == 21 and again[1] == final and again[2] == []  # the own episode, deviations or none
    assert len(samples) == 3
    for x, other, q, advantage, step in samples:
        assert x.shape == worker.env.observation_space.shape  # type: ignore[attr-defined]
        assert 0 <= other < 9 and 0 < q < 1 and np.isfinite(advantage) and 0 <= step < 20
        own = int(torch.argmax(self_critical.joint_logits(worker.policy, torch.as_tensor(x[None]))))  # type: ignore[attr-defined]
        assert other != own


def test_that_the_update_raises_the_probability_of_a_deviation_that_paid(
        self_critical: ModuleType, worker: object) -> None:
    from stable_baselines3 import PPO

    policy = PPO.load(RUN / "latest.zip", device="cpu").policy
    obs, _ = worker.env.reset(seed=5)  # type: ignore[attr-defined]
    x = np.repeat(obs[None].astype(np.float32), 64, axis=0)  # one state, 64 times
    with torch.no_grad():
        own = int(torch.argmax(self_critical.joint_logits(policy, torch.as_tensor(x[:1]))))
    good, bad = (own + 1) % 9, (own + 2) % 9
    data = [(x[i], good if i % 2 else bad, 0.1, 0.2 if i % 2 else -0.2, 5) for i in range(64)]

    def p(action: int) -> float:
        with torch.no_grad():
            return float(torch.softmax(self_critical.joint_logits(policy, torch.as_tensor(x[:1])) / 4.0, 1)[0, action])

    before_good, before_bad = p(good), p(bad)
    optimiser = torch.optim.Adam(policy.parameters(), lr=1e-3)
    for k in range(5):
        self_critical.update(policy, optimiser, data, 4.0, k)
    assert p(good) > before_good and p(bad) < before_bad
