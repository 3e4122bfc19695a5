"""Validated arrays: the known rig (Table 3) and the landmark observations (Table 2).

These are what a model and an objective consume. They are built from a dataset file by
:meth:`handeye_jax.dataset.Dataset.observations`, or directly from arrays.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .. import geometry as geo


class Rig(eqx.Module):
    """What is known about the set-up: intrinsics, capture pose and the hand-angle convention.

    Attributes:
        fx_px, fy_px: focal lengths in pixels.
        cx_px, cy_px: principal point in pixels.
        capture_position_mm: hand position ``(xh, yh, zh)`` when the picture was taken, in mm,
            in the base frame; the hand points down (eq. 1).
        angle_zero_deg, angle_sign: the controller's hand-angle convention,
            ``φ = zero + sign·θh`` (paper notes, item 3).
        capture_hand_angle_deg: the hand angle θc at the capture, deg, or ``None`` for the
            paper's capture at φ = 0 (eq. 1). At a capture the hand points down turned by
            ``φc = zero + sign·θc``: ``R_base_hand = Ry(-180)·Rz(φc)``. The camera is mounted
            on the hand, so it turns with it.
    """

    fx_px: Float[Array, ""]
    fy_px: Float[Array, ""]
    cx_px: Float[Array, ""]
    cy_px: Float[Array, ""]
    capture_position_mm: Float[Array, "3"]
    angle_zero_deg: Float[Array, ""]
    angle_sign: Float[Array, ""]
    capture_hand_angle_deg: Float[Array, ""] | None

    def __init__(
        self,
        fx_px: Float[ArrayLike, ""],
        fy_px: Float[ArrayLike, ""],
        cx_px: Float[ArrayLike, ""],
        cy_px: Float[ArrayLike, ""],
        capture_position_mm: Float[ArrayLike, "3"],
        angle_zero_deg: Float[ArrayLike, ""],
        angle_sign: Float[ArrayLike, ""],
        capture_hand_angle_deg: Float[ArrayLike, ""] | None = None,
    ):
        self.fx_px = jnp.asarray(fx_px, dtype=float)
        self.fy_px = jnp.asarray(fy_px, dtype=float)
        self.cx_px = jnp.asarray(cx_px, dtype=float)
        self.cy_px = jnp.asarray(cy_px, dtype=float)
        self.capture_position_mm = jnp.asarray(capture_position_mm, dtype=float)
        self.angle_zero_deg = jnp.asarray(angle_zero_deg, dtype=float)
        self.angle_sign = jnp.asarray(angle_sign, dtype=float)
        self.capture_hand_angle_deg = (
            None if capture_hand_angle_deg is None
            else jnp.asarray(capture_hand_angle_deg, dtype=float)
        )  # fmt: skip

    def p_camera(
        self, image_px: Float[Array, "n 2"], depth_mm: Float[Array, " n"]
    ) -> Float[Array, "n 3"]:
        """Back-project image points with their depths into the camera frame (eq. 4), mm."""
        return geo.backproject(image_px, depth_mm, self.fx_px, self.fy_px, self.cx_px, self.cy_px)

    def T_base_hand_capture(self) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
        """``(R_base_hand, t_base_hand)`` at the capture pose: eq. (1), ``Ry(-180)``, turned by
        ``Rz(φc)`` when the capture's hand angle is given."""
        if self.capture_hand_angle_deg is None:
            return geo.R_base_hand_down(), self.capture_position_mm
        R = geo.matmul3(geo.R_base_hand_down(), geo.rot_z(self.capture_phi_deg()))
        return R, self.capture_position_mm

    def capture_phi_deg(self) -> Float[Array, ""]:
        """The hand's turn φc at the capture, deg (0 for the paper's capture)."""
        if self.capture_hand_angle_deg is None:
            return jnp.zeros(())
        return self.phi_deg(self.capture_hand_angle_deg)

    def phi_deg(self, hand_angle_deg: Float[ArrayLike, "*n"]) -> Float[Array, "*n"]:
        """The angle that turns the pen offset for hand angles ``θh`` in degrees."""
        return geo.pen_angle_deg(hand_angle_deg, self.angle_zero_deg, self.angle_sign)


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
