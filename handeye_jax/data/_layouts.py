"""Landmark layouts on the tablet, px."""

from __future__ import annotations

import numpy as np


def snake_grid_px(
    xs: tuple[float, ...] = (400.0, 720.0, 1040.0), ys: tuple[float, ...] = (150.0, 350.0, 550.0)
) -> np.ndarray:
    """Landmarks on a grid, numbered in snake order (the paper's 3×3 layout by default), px."""
    rows = []
    for r, y in enumerate(ys):
        row = [(x, y) for x in xs]
        rows.extend(row[::-1] if r % 2 else row)
    return np.array(rows, dtype=float)
