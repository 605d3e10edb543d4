"""The feature layer in plain Python (the deployed policy's) against torch's (the trained network's)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tumblebot.sim.control.features import FEATURES, compute
from tumblebot.sim.observation import LAYOUTS
from tumblebot.training.features import feature_names, features_for


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_that_numpy_features_equal_torch_features_for_every_layout(layout: str) -> None:
    rng = np.random.default_rng(7)
    x = rng.normal(scale=1.5, size=(4000, len(LAYOUTS[layout]))).astype(np.float32)
    if layout != "thesis":
        x[:, 9:13] = rng.uniform(0.02, 0.45, size=(4000, 4))  # a design: positive lengths
        proposals = x[:, len(LAYOUTS["memory"]):]  # goto's actions, 0/1/2 (none in context and memory)
        proposals[:] = rng.integers(0, 3, size=proposals.shape)
    x[:7, 3:7] = 0.0  # a zero quaternion, as a clipped observation can hold
    module, size = features_for(x.shape[1])
    with torch.no_grad():
        expected = module(torch.from_numpy(x)).numpy()
    assert feature_names(layout) == FEATURES[layout] and size == len(FEATURES[layout])
    np.testing.assert_allclose(compute(layout, x), expected, rtol=2e-6, atol=2e-6)
