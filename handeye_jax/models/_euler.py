"""Rotation matrices back to the models' angles (NumPy): the inverse of ``geometry.rot_zyx``."""

from __future__ import annotations

import numpy as np
from jaxtyping import Float


def wrap_deg(angle_deg: float) -> float:
    """An angle in degrees brought into [-180, 180)."""
    return float((angle_deg + 180.0) % 360.0 - 180.0)


def zyx_angles_deg(R: Float[np.ndarray, "3 3"]) -> tuple[float, float, float]:
    """``(γ, β, α)`` with ``R = Rz(γ)·Ry(β)·Rx(α)`` and ``|β| <= 90``, degrees.

    Of the two such triples of a rotation (the other is ``(γ + 180, 180 − β, α + 180)``) this
    is the one with the smaller tilt; at ``|β| = 90`` (gimbal lock) α is taken as 0.
    """
    R = np.asarray(R, dtype=float)
    beta = float(np.degrees(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))))
    if np.hypot(R[2, 1], R[2, 2]) < 1e-12:  # gimbal lock: only γ − α (or γ + α) is defined
        return wrap_deg(float(np.degrees(np.arctan2(-R[0, 1], R[1, 1])))), beta, 0.0
    alpha = float(np.degrees(np.arctan2(R[2, 1], R[2, 2])))
    gamma = float(np.degrees(np.arctan2(R[1, 0], R[0, 0])))
    return gamma, beta, alpha
