from typing import Any

import numpy as np
import pytest

from tumblebot.sim.errors import SimError
from tumblebot.sim.world.terrain import TerrainConfig, perlin, tile_heightfield


def test_that_perlin_noise_is_seeded_and_smooth() -> None:
    x, y = np.meshgrid(np.linspace(0, 3, 60), np.linspace(0, 3, 60))
    a = perlin(x, y, 1.0, np.random.default_rng(1))
    b = perlin(x, y, 1.0, np.random.default_rng(1))
    c = perlin(x, y, 1.0, np.random.default_rng(2))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.abs(np.diff(a, axis=1)).max() < 0.2  # neighbouring samples stay close
    assert np.abs(a).max() <= 1.0


def test_that_terrain_is_made_of_flat_tiles_within_the_height_range() -> None:
    cfg = TerrainConfig(cells=64, cell_size=0.05, tile_size=0.2, max_height=0.04)
    h = tile_heightfield(cfg, np.random.default_rng(0))
    assert h.shape == (64, 64)
    assert h.min() == pytest.approx(0.0)
    assert h.max() == pytest.approx(0.04)
    # 0.2 m tiles are 4 cells wide: far fewer distinct heights than cells.
    assert len(np.unique(h)) <= (64 // 4 + 1) ** 2


@pytest.mark.parametrize("kwargs", [{"cells": 2}, {"cell_size": 0.0}, {"max_height": -0.1}])
def test_that_bad_terrain_parameters_are_rejected(kwargs: dict[str, Any]) -> None:
    with pytest.raises(SimError):
        TerrainConfig(**kwargs)
