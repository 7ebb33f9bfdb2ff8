"""The rocky table: 169 fixed bumps on a jittered 13x13 grid, generated deterministically."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..urdf import boxes_urdf

ROCK_SEED = 2023
ROCK_GRID = 13
ROCK_HALF_SIDE = 0.007  # 14 x 14 mm footprint
ROCK_HALF_HEIGHT = (0.003, 0.005)  # 6-10 mm tall
ROCK_JITTER = 0.01
ROCK_RGBA = (0.35, 0.35, 0.35, 1.0)


@lru_cache(maxsize=1)
def rock_boxes() -> np.ndarray:
    """(169, 6) rows of (x, y, z, half_x, half_y, half_z); x in [-0.43, 0.23], y in [-0.33, 0.33]."""
    rng = np.random.default_rng(ROCK_SEED)
    gx, gy = np.meshgrid(
        np.linspace(-0.42, 0.22, ROCK_GRID), np.linspace(-0.32, 0.32, ROCK_GRID), indexing="ij"
    )
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1) + rng.uniform(
        -ROCK_JITTER, ROCK_JITTER, (ROCK_GRID**2, 2)
    )
    hz = rng.uniform(*ROCK_HALF_HEIGHT, ROCK_GRID**2)
    half = np.full(ROCK_GRID**2, ROCK_HALF_SIDE)
    boxes = np.column_stack([xy, hz, half, half, hz])
    boxes.flags.writeable = False
    return boxes


def rocks_urdf() -> str:
    return boxes_urdf("rocks", rock_boxes(), ROCK_RGBA)


def surface_height(boxes: np.ndarray, xy: np.ndarray, half_xy: np.ndarray) -> float:
    """Height of the highest box under an axis-aligned footprint centred at ``xy`` (0 if none)."""
    under = np.all(np.abs(boxes[:, :2] - xy) < boxes[:, 3:5] + half_xy, axis=1)
    return float((2 * boxes[under, 5]).max(initial=0.0))
