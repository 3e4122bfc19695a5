"""From observed image points to hand commands: eq. (8) after stage 1, eq. (25) after stage 2."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._base import AbstractCorrection, AbstractModel
from ._rig import Rig


class Targets(eqx.Module):
    """Points to touch, as seen: image point (px), depth (mm), the hand angle to touch with
    (deg), and the capture pose each was seen from (hand position mm ``(k, 3)``, hand angle
    deg ``(k,)``; ``None``: the rig's capture)."""

    image_px: Float[Array, "k 2"]
    depth_mm: Float[Array, " k"]
    hand_angle_deg: Float[Array, " k"]
    capture_position_mm: Float[Array, "k 3"] | None = None
    capture_hand_angle_deg: Float[Array, " k"] | None = None

    @property
    def k(self) -> int:
        return self.image_px.shape[0]


def hand_command(
    model: AbstractModel,
    rig: Rig,
    targets: Targets,
    *,
    correction: AbstractCorrection | None = None,
    centres_mm: Float[Array, "2 2"] | None = None,
    pen_minus_camera_mm: Float[Array, ""] | None = None,
) -> Float[Array, "n 2"] | Float[Array, "n 3"]:
    """Where to send the hand, ``(x, y)`` (or ``(x, y, z)``) in mm in the base frame, so the
    pen touches each point.

    The model, rig and targets are positional; what changes the answer from eq. (8) is named
    (keywords only): the correction, the height.

    A target is any point seen in a picture at its depth, on the tablet or not, taken from any
    capture pose: the hand pointing down, at ``targets.capture_position_mm``, turned by
    ``φc = zero + sign·θc`` (the camera turns with it).

    Args:
        model: a fitted stage-1 model.
        rig: the rig the model was fitted with (intrinsics, capture pose, angle convention).
        targets: each target's image point (px), depth (mm), the hand angle θh the robot will
            touch with (deg), and the capture pose it was seen from (default: the rig's).
        correction: the fitted stage-2 correction; ``None`` gives eq. (8) (stage 1).
        centres_mm: the correction's centres of rotation (rows: A1, A2), fixed at calibration.
        pen_minus_camera_mm: the calibration's ``z_p − z_c``, mm; given, the commands carry
            the hand's height as a third column (the affine correction is planar: z has none).
    """
    image_px, depth_mm = targets.image_px, targets.depth_mm
    position, angle = targets.capture_position_mm, targets.capture_hand_angle_deg
    if position is None and angle is None:
        x_b = model.image_to_base(image_px, depth_mm, rig)
    else:
        n = image_px.shape[0]
        position = rig.capture_position_mm if position is None else position
        phi = rig.capture_phi_deg() if angle is None else rig.phi_deg(angle)
        x_b = model.image_to_base(image_px, depth_mm, rig,
                                  jnp.broadcast_to(position, (n, 3)),
                                  jnp.broadcast_to(phi, (n,)))  # fmt: skip
    x_bi = x_b[:, :2]
    offset = model.pen_offset(rig.phi_deg(targets.hand_angle_deg))[:, :2]
    if correction is None:
        xy = x_bi - offset
    else:
        xy = correction.second(correction.first(x_bi, centres_mm[0]) - offset, centres_mm[1])
    if pen_minus_camera_mm is None:
        return xy
    # The hand points down: the pen tip is z_p below the hand, the point z_c below x_b's z.
    return jnp.concatenate([xy, (x_b[:, 2] + pen_minus_camera_mm)[:, None]], axis=1)
