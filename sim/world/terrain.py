"""Seeded tile terrain from Perlin noise (thesis Fig. 2.2), in numpy.

:func:`perlin` is classic 2-D gradient noise; :func:`tile_heightfield` samples it once
per square tile and returns a heightfield grid of flat-topped tiles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tumblebot.sim.errors import SimError


def _fade(t: np.ndarray) -> np.ndarray:
    return np.asarray(t * t * t * (t * (t * 6 - 15) + 10))


def perlin(points_x: np.ndarray, points_y: np.ndarray, period: float, rng: np.random.Generator) -> np.ndarray:
    """Perlin noise in about [−0.7, 0.7] at the given points (any shape), lattice spacing
    ``period``; the random gradients come from ``rng``."""
    gx = points_x / period
    gy = points_y / period
    x0 = np.floor(gx).astype(np.int64)
    y0 = np.floor(gy).astype(np.int64)
    ox, oy = int(x0.min()), int(y0.min())
    nx, ny = int(x0.max()) - ox + 2, int(y0.max()) - oy + 2
    angles = rng.uniform(0.0, 2 * np.pi, size=(nx, ny))
    grad = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    fx, fy = gx - x0, gy - y0
    ix, iy = x0 - ox, y0 - oy

    def corner(dx: int, dy: int) -> np.ndarray:
        g = grad[ix + dx, iy + dy]
        return g[..., 0] * (fx - dx) + g[..., 1] * (fy - dy)

    u, v = _fade(fx), _fade(fy)
    top = corner(0, 0) * (1 - u) + corner(1, 0) * u
    bottom = corner(0, 1) * (1 - u) + corner(1, 1) * u
    return np.asarray(top * (1 - v) + bottom * v)


@dataclass(frozen=True)
class TerrainConfig:
    """Tile terrain parameters (metres).

    Attributes:
        cells: heightfield grid size per side (64–128 keeps stepping cheap).
        cell_size: grid spacing; ``cells × cell_size`` is the terrain's side length.
        tile_size: side of one flat-topped tile (a multiple of ``cell_size``).
        max_height: tile heights lie in ``[0, max_height]``.
        noise_period: Perlin lattice spacing; larger gives smoother hills of tiles.
    """

    cells: int = 128
    cell_size: float = 0.05
    tile_size: float = 0.20
    max_height: float = 0.03
    noise_period: float = 1.0

    def __post_init__(self) -> None:
        if not 8 <= self.cells <= 1024:
            raise SimError(f"terrain cells={self.cells} must be in [8, 1024]")
        for name in ("cell_size", "tile_size", "noise_period"):
            if not getattr(self, name) > 0:
                raise SimError(f"terrain {name}={getattr(self, name)} must be positive")
        if not 0 <= self.max_height < 1.0:
            raise SimError(f"terrain max_height={self.max_height} m must be in [0, 1)")

    @property
    def side(self) -> float:
        return self.cells * self.cell_size


def tile_heightfield(config: TerrainConfig, rng: np.random.Generator) -> np.ndarray:
    """Heights (``cells × cells``, metres, row = y, column = x) of flat-topped tiles
    centred on the origin; each tile's height is the Perlin noise at its centre."""
    n = config.cells
    coords = (np.arange(n) - (n - 1) / 2) * config.cell_size
    tile_index = np.floor(coords / config.tile_size)
    tile_centre = (tile_index + 0.5) * config.tile_size
    tx, ty = np.meshgrid(tile_centre, tile_centre)  # rows vary along y
    noise = perlin(tx, ty, config.noise_period, rng)
    lo, hi = float(noise.min()), float(noise.max())
    scaled = (noise - lo) / (hi - lo) if hi > lo else np.zeros_like(noise)
    return np.asarray(scaled * config.max_height)


def height_at(heights: np.ndarray, config: TerrainConfig, x: float, y: float, radius: float = 0.0) -> float:
    """Highest terrain point within ``radius`` of ``(x, y)`` (0 outside the grid)."""
    n = config.cells
    coords = (np.arange(n) - (n - 1) / 2) * config.cell_size
    cols = np.abs(coords - x) <= radius + config.cell_size
    rows = np.abs(coords - y) <= radius + config.cell_size
    patch = heights[np.ix_(rows, cols)]
    return float(patch.max()) if patch.size else 0.0
