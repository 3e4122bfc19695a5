"""Evaluation targets: where the page draws the points to touch, tablet (CSS) px.

Targets come from a dataset (its landmarks: the paper's in-sample Tables 9 and 12), from a
targets file (held-out points), or from a new grid drawn on the page.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._core import Reader, describe, load_json
from ..data import snake_grid_px
from ._posts import MAX_SCREEN_PX, MAX_TOUCHES

TARGETS_FORMAT = "handeye-jax.targets/1"
MAX_GRID_SIDE = 30


def load_targets(path: str | Path) -> np.ndarray:
    """Targets ``(n, 2)`` in tablet px from a file; raises :class:`InputError`.

    A ``.toml`` file is read as a dataset and gives its landmarks. Any other file must be JSON:
    ``{"format": "handeye-jax.targets/1", "tablet_px": [[x, y], ...]}`` (``format`` optional).
    """
    path = Path(path)
    if path.suffix.lower() == ".toml":
        from ..data import load_dataset

        return load_dataset(path).tablet_px
    r = Reader(path)
    doc = load_json(path, what="targets")
    if not isinstance(doc, dict) or "tablet_px" not in doc:
        r.fail("tablet_px", 'missing; expected {"tablet_px": [[x, y], ...]} in px')
    if doc.get("format", TARGETS_FORMAT) != TARGETS_FORMAT:
        r.fail("format", f"expected {TARGETS_FORMAT!r} (got {describe(doc['format'])})")
    points = doc["tablet_px"]
    if not isinstance(points, list) or not 1 <= len(points) <= MAX_TOUCHES:
        r.fail("tablet_px", f"must be an array of 1 to {MAX_TOUCHES} [x, y] points")
    xy = np.array([r.vector(p, f"tablet_px[{i}]", 2) for i, p in enumerate(points)])
    bad = np.flatnonzero(((xy < 0) | (xy > MAX_SCREEN_PX)).any(axis=1))
    if bad.size:
        r.fail(f"tablet_px[{bad[0]}]", f"must lie on a screen, within [0, {MAX_SCREEN_PX:g}] px")
    return xy


def grid_targets(
    cols: int, rows: int, left_px: float, top_px: float, right_px: float, bottom_px: float
) -> np.ndarray:
    """A ``cols`` × ``rows`` grid spanning the rectangle, in snake order (the paper's order).

    Args:
        cols, rows: number of columns and rows, 1 to 30 each, at most 100 targets in all.
        left_px, top_px, right_px, bottom_px: the rectangle's edges, CSS px from the page's
            top-left corner; a single column (row) sits at ``left_px`` (``top_px``).

    Raises ``ValueError`` naming the bad argument.
    """
    for name, n in (("cols", cols), ("rows", rows)):
        if not 1 <= n <= MAX_GRID_SIDE:
            raise ValueError(f"{name}: must be 1 to {MAX_GRID_SIDE} (got {n})")
    if cols * rows > MAX_TOUCHES:
        raise ValueError(f"rows: a grid of at most {MAX_TOUCHES} targets (got {cols} x {rows})")
    edges = {"left": left_px, "top": top_px, "right": right_px, "bottom": bottom_px}
    for name, v in edges.items():
        if not 0.0 <= v <= MAX_SCREEN_PX:
            raise ValueError(f"{name}: must be within [0, {MAX_SCREEN_PX:g}] px (got {v})")
    if cols > 1 and not left_px < right_px:
        raise ValueError(f"right: must be > left ({left_px}) (got {right_px})")
    if rows > 1 and not top_px < bottom_px:
        raise ValueError(f"bottom: must be > top ({top_px}) (got {bottom_px})")
    xs = np.linspace(left_px, right_px, cols) if cols > 1 else np.array([left_px])
    ys = np.linspace(top_px, bottom_px, rows) if rows > 1 else np.array([top_px])
    return snake_grid_px(tuple(np.round(xs, 3)), tuple(np.round(ys, 3)))
