"""The known rig: intrinsics, the capture pose and the hand-angle convention (Table 3).

The fixed part of the transform chain, beside the fitted models: a model maps image points
to the base frame through it (eqs. 1-4).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

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
