"""Validated arrays: the known rig (Table 3) and the landmark observations (Table 2).

These are what a model and an objective consume. They are built from a dataset file by
:meth:`handeye_jax.dataset.Dataset.observations`, or directly from arrays.
"""

from __future__ import annotations

import equinox as eqx
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ..models import Rig


class Observations(eqx.Module):
    """One calibration's landmark data, in mm / deg / px, plus the rig it was taken with.

    Attributes:
        rig: the known quantities.
        image_px: ``(u, v)`` of each landmark in the captured picture, px.
        depth_mm: depth ``z_c`` at ``(u, v)``, mm.
        tablet_mm: where each landmark is drawn on the tablet, converted with eq. (9), mm.
        hand_xy_mm: hand position ``(x_r, y_r)`` when the pen touched the landmark, mm.
        hand_angle_deg: hand angle ``θh`` at that touch, degrees.
        touch_error_mm: where the pen touched minus where the landmark is, in the tablet
            frame, mm (the tablet reports it in px; eq. 9 converts).
        centre_index: the landmark whose mapped position is the centre of rotation of the
            stage-2 affine maps (the paper's middle landmark, m = 4).
        capture_position_mm, capture_hand_angle_deg: each row's capture pose, mm ``(n, 3)``
            and deg ``(n,)``, for data from several captures; ``None`` (the paper's single
            capture): every row was seen from ``rig``'s capture pose.
        hand_z_mm: the hand's height at each row's touch as the controller reports it, mm
            (NaN where not recorded), or ``None``.
        capture_index, touch_index: each row's capture and touch in the dataset, or ``None``.
        mm_per_tablet_px: the tablet px the touch errors were converted from, mm (eq. 9), for
            the noise of their rounding; ``None``: not known.

    With several captures a *row* is one view of a landmark (a capture that sees it) paired
    with one touch of it: ``f1`` compares the view with the tablet chain, ``f2`` with the
    touch. A landmark seen from k captures and touched once gives k rows.
    """

    rig: Rig
    image_px: Float[Array, "n 2"]
    depth_mm: Float[Array, " n"]
    tablet_mm: Float[Array, "n 2"]
    hand_xy_mm: Float[Array, "n 2"]
    hand_angle_deg: Float[Array, " n"]
    touch_error_mm: Float[Array, "n 2"]
    centre_index: int = eqx.field(static=True)
    capture_position_mm: Float[Array, "n 3"] | None = None
    capture_hand_angle_deg: Float[Array, " n"] | None = None
    hand_z_mm: Float[Array, " n"] | None = None
    capture_index: Int[Array, " n"] | None = None
    touch_index: Int[Array, " n"] | None = None
    mm_per_tablet_px: Float[Array, ""] | None = None

    @property
    def n_landmarks(self) -> int:
        """The number of rows (landmarks, for the paper's single capture)."""
        return self.image_px.shape[0]

    @property
    def per_capture(self) -> bool:
        """Whether each row carries its own capture pose."""
        return self.capture_position_mm is not None

    def phi_deg(self) -> Float[Array, " n"]:
        """The pen-offset angle φ of each touch, degrees."""
        return self.rig.phi_deg(self.hand_angle_deg)

    def capture_phi_deg(self) -> Float[Array, " n"] | None:
        """The hand's turn φc at each row's capture, deg (``None``: the rig's capture)."""
        if self.capture_hand_angle_deg is None:
            return None
        return self.rig.phi_deg(self.capture_hand_angle_deg)


def centre_landmark(tablet_xy: Float[ArrayLike, "n 2"]) -> int:
    """Index of the landmark nearest the centroid of the drawn landmarks.

    For the paper's 3×3 snake grid this is m = 4, the paper's centre of rotation (eq. 24).
    """
    xy = np.asarray(tablet_xy, dtype=float)
    return int(np.argmin(np.linalg.norm(xy - xy.mean(axis=0), axis=1)))
