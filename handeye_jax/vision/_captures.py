"""The pictures the toolkit recommends: captures planned from a dataset's first one.

One picture from one pose leaves the camera mount's x offset trading off against its tilt
(``xc``/``βc``, ``yc``/``αc``); pictures from other heights, through a mount turned by
other hand angles, tell them apart. :func:`plan_captures` adds those captures to a dataset,
empty (no landmark seen yet), so that the tablet page lists their poses and ``detect
--capture K`` fills each.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .._core import RECOMMENDED_CAPTURES as RECOMMENDED
from ..data import Capture, Dataset


def plan_captures(
    dataset: Dataset,
    rises_mm: Sequence[float] = tuple(r for r, _ in RECOMMENDED),
    turns_deg: Sequence[float] = tuple(t for _, t in RECOMMENDED),
) -> tuple[Dataset, list[int]]:
    """The dataset with an empty capture planned for each ``(rise, turn)``.

    Args:
        dataset: a dataset with at least one capture; the plan starts from its first.
        rises_mm: how much higher than the first capture each picture is taken, mm (the hand's
            z in the base frame; x and y stay the first capture's).
        turns_deg: the hand angle of each picture minus the first capture's, deg.

    Returns:
        The new dataset (version 2) and the index of each planned capture. A planned pose
        that a capture of the dataset already has is not added again; its index is given.

    Raises:
        ValueError: ``rises_mm`` and ``turns_deg`` differ in length, or hold a number that
            is not finite.
    """
    rises, turns = np.asarray(rises_mm, dtype=float), np.asarray(turns_deg, dtype=float)
    if rises.shape != turns.shape or rises.ndim != 1:
        raise ValueError(f"give one turn per rise (got {rises.size} rises, {turns.size} turns)")
    if not (np.isfinite(rises).all() and np.isfinite(turns).all()):
        raise ValueError("rises and turns must be finite")
    first = dataset.captures[0]
    caps = list(dataset.captures)
    indices = []
    for rise, turn in zip(rises, turns, strict=True):
        position = first.hand_position_mm + np.array([0.0, 0.0, rise])
        angle = first.hand_angle_deg + turn
        same = [k for k, c in enumerate(caps) if c.hand_angle_deg == angle
                and np.array_equal(c.hand_position_mm, position)]  # fmt: skip
        if same:
            indices.append(same[0])
            continue
        caps.append(Capture(position, angle, [], np.zeros((0, 2)), np.zeros(0)))
        indices.append(len(caps) - 1)
    return dataset.replace(captures=caps, version=2), indices
