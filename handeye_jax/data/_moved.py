"""The same measurements in another base frame: the robot turned about its vertical axis and
moved, everything else (the pictures, the tablet, the pen) as it was."""

from __future__ import annotations

import dataclasses

import numpy as np

from ._dataset import Dataset


def moved_base(dataset: Dataset, shift_mm=(0.0, 0.0), turn_deg: float = 0.0) -> Dataset:
    """``dataset`` as a robot whose base frame is turned by ``turn_deg`` about its z axis and
    then shifted by ``shift_mm`` (x, y) would record it: every capture and touch position
    turned and shifted, every hand angle changed to match the turn.

    The hand points down (eq. 1), so turning the world by ψ about z turns the hand's
    ``φ = zero + sign·θ`` by −ψ: each hand angle θ becomes ``θ − sign·ψ``. A calibration of
    the result finds the same camera mount, pen and F, with the tablet moved and turned.

    Args:
        dataset: the measurements.
        shift_mm: the base-frame shift ``(dx, dy)``, mm.
        turn_deg: the turn about the base's z axis, deg.
    """
    r = np.deg2rad(float(turn_deg))
    R = np.array([[np.cos(r), -np.sin(r)], [np.sin(r), np.cos(r)]])
    shift = np.asarray(shift_mm, dtype=float).reshape(2)
    dtheta = -dataset.hand_angle_sign * float(turn_deg)

    def place(xy: np.ndarray) -> np.ndarray:
        return np.asarray(xy, dtype=float) @ R.T + shift

    captures = []
    for c in dataset.captures:
        position = np.array(c.hand_position_mm, dtype=float)
        position[:2] = place(position[:2])
        captures.append(dataclasses.replace(c, hand_position_mm=position,
                                            hand_angle_deg=c.hand_angle_deg + dtheta))  # fmt: skip
    version = dataset.version if turn_deg == 0 else 2  # version 1 holds no capture angle
    fields = {name: getattr(dataset, name) for name in Dataset.FIELDS}
    fields.update(captures=tuple(captures), hand_xy_mm=place(dataset.hand_xy_mm),
                  hand_angle_deg=dataset.hand_angle_deg + dtheta, version=version)  # fmt: skip
    return Dataset(**fields)
