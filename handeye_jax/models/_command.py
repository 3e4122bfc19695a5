"""From observed image points to hand commands: eq. (8) after stage 1, eq. (25) after stage 2."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._base import AbstractCorrection, AbstractModel
from ._rig import Rig


def hand_command(
    model: AbstractModel,
    rig: Rig,
    image_px: Float[Array, "n 2"],
    depth_mm: Float[Array, " n"],
    hand_angle_deg: Float[Array, " n"],
    *,
    correction: AbstractCorrection | None = None,
    centres_mm: Float[Array, "2 2"] | None = None,
    capture_position_mm: Float[Array, "n 3"] | None = None,
    capture_hand_angle_deg: Float[Array, " n"] | None = None,
    pen_minus_camera_mm: Float[Array, ""] | None = None,
) -> Float[Array, "n 2"] | Float[Array, "n 3"]:
    """Where to send the hand, ``(x, y)`` (or ``(x, y, z)``) in mm in the base frame, so the
    pen touches each point.

    The model, rig and targets are positional; what changes the answer from eq. (8) at the
    rig's capture is named (keywords only): the correction, the capture pose, the height.

    A target is any point seen in a picture at its depth, on the tablet or not, taken from any
    capture pose: the hand pointing down, at ``capture_position_mm``, turned by
    ``φc = zero + sign·θc`` (the camera turns with it).

    Args:
        model: a fitted stage-1 model.
        rig: the rig the model was fitted with (intrinsics, capture pose, angle convention).
        image_px: ``(u, v)`` of each target in the captured picture, px.
        depth_mm: depth at each target, mm.
        hand_angle_deg: the hand angle θh the robot will touch with, deg.
        correction: the fitted stage-2 correction; ``None`` gives eq. (8) (stage 1).
        centres_mm: the correction's centres of rotation (rows: A1, A2), fixed at calibration.
        capture_position_mm: the hand position when each target's picture was taken, mm,
            ``(n, 3)``; ``None``: the rig's capture.
        capture_hand_angle_deg: the hand angle θc then, deg, ``(n,)``; ``None``: the rig's.
        pen_minus_camera_mm: the calibration's ``z_p − z_c``, mm; given, the commands carry
            the hand's height as a third column (the affine correction is planar: z has none).
    """
    if capture_position_mm is None and capture_hand_angle_deg is None:
        x_b = model.image_to_base(image_px, depth_mm, rig)
    else:
        n = image_px.shape[0]
        position = rig.capture_position_mm if capture_position_mm is None else (
            capture_position_mm)  # fmt: skip
        phi = (rig.capture_phi_deg() if capture_hand_angle_deg is None
               else rig.phi_deg(capture_hand_angle_deg))  # fmt: skip
        x_b = model.image_to_base(image_px, depth_mm, rig,
                                  jnp.broadcast_to(position, (n, 3)),
                                  jnp.broadcast_to(phi, (n,)))  # fmt: skip
    x_bi = x_b[:, :2]
    offset = model.pen_offset(rig.phi_deg(hand_angle_deg))[:, :2]
    if correction is None:
        xy = x_bi - offset
    else:
        xy = correction.second(correction.first(x_bi, centres_mm[0]) - offset, centres_mm[1])
    if pen_minus_camera_mm is None:
        return xy
    # The hand points down: the pen tip is z_p below the hand, the point z_c below x_b's z.
    return jnp.concatenate([xy, (x_b[:, 2] + pen_minus_camera_mm)[:, None]], axis=1)
