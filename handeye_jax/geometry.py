"""Pure, jittable geometry of the paper's transform chain, eqs. (1)-(11).

Frame names follow the jaxlie convention: ``R_a_b`` rotates vectors expressed in frame ``b``
into frame ``a``, and ``t_a_b`` is the origin of ``b`` expressed in ``a``. Frames are the
paper's: ``base`` (Σb), ``hand`` (Σh), ``camera`` (Σc), ``image`` (Σi) and ``tablet`` (Σt).

All angles are in degrees (the paper's unit), all lengths in millimetres, image coordinates in
pixels. Every function is dtype-polymorphic; the public API runs it in float64 (see
:mod:`handeye_jax._x64`).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

MM_PER_INCH = 25.4

# The capture and touch poses point the tool flange straight down: eq. (1)'s Ry(-180).
HAND_DOWN_Y_DEG = -180.0


def rot_x(angle_deg: Float[ArrayLike, ""]) -> Float[Array, "3 3"]:
    """Rotation about x by ``angle_deg`` degrees (right-handed)."""
    a = jnp.deg2rad(angle_deg)
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack(
        [jnp.stack([one, zero, zero]), jnp.stack([zero, c, -s]), jnp.stack([zero, s, c])]
    )


def rot_y(angle_deg: Float[ArrayLike, ""]) -> Float[Array, "3 3"]:
    """Rotation about y by ``angle_deg`` degrees (right-handed)."""
    a = jnp.deg2rad(angle_deg)
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack(
        [jnp.stack([c, zero, s]), jnp.stack([zero, one, zero]), jnp.stack([-s, zero, c])]
    )


def rot_z(angle_deg: Float[ArrayLike, ""]) -> Float[Array, "3 3"]:
    """Rotation about z by ``angle_deg`` degrees (right-handed)."""
    a = jnp.deg2rad(angle_deg)
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack(
        [jnp.stack([c, -s, zero]), jnp.stack([s, c, zero]), jnp.stack([zero, zero, one])]
    )


def htm(R: Float[Array, "3 3"], t: Float[Array, "3"]) -> Float[Array, "4 4"]:
    """Homogeneous transform matrix ``[[R, t], [0, 1]]``."""
    bottom = jnp.array([0.0, 0.0, 0.0, 1.0], dtype=R.dtype)
    return jnp.concatenate([jnp.concatenate([R, t[:, None]], axis=1), bottom[None]], axis=0)


def transform_points(
    R_a_b: Float[Array, "3 3"], t_a_b: Float[Array, "3"], p_b: Float[Array, "n 3"]
) -> Float[Array, "n 3"]:
    """Map points ``p_b`` (rows, expressed in frame b) into frame a: ``R_a_b p + t_a_b``."""
    return p_b @ R_a_b.T + t_a_b


def R_base_hand_down() -> Float[Array, "3 3"]:
    """Orientation of the hand at the capture pose, eq. (1): ``Ry(-180)``."""
    return rot_y(HAND_DOWN_Y_DEG)


def backproject(
    image_px: Float[Array, "n 2"],
    depth_mm: Float[Array, " n"],
    fx_px: Float[ArrayLike, ""],
    fy_px: Float[ArrayLike, ""],
    cx_px: Float[ArrayLike, ""],
    cy_px: Float[ArrayLike, ""],
) -> Float[Array, "n 3"]:
    """Pinhole back-projection, eq. (4): image pixels and depth to camera-frame points.

    Args:
        image_px: ``(u, v)`` of each point in pixels.
        depth_mm: distance ``z_c`` along the optical axis in mm, as the RGB-D camera reports it.
        fx_px, fy_px: focal lengths in pixels.
        cx_px, cy_px: principal point in pixels.

    Returns:
        ``p_camera`` in mm, one row per point.
    """
    x = depth_mm * (image_px[:, 0] - cx_px) / fx_px
    y = depth_mm * (image_px[:, 1] - cy_px) / fy_px
    return jnp.stack([x, y, depth_mm], axis=-1)


def project(
    p_camera_mm: Float[Array, "n 3"],
    fx_px: Float[ArrayLike, ""],
    fy_px: Float[ArrayLike, ""],
    cx_px: Float[ArrayLike, ""],
    cy_px: Float[ArrayLike, ""],
) -> tuple[Float[Array, "n 2"], Float[Array, " n"]]:
    """Pinhole projection, eq. (3); the inverse of :func:`backproject`.

    Returns ``(image_px, depth_mm)``.
    """
    z = p_camera_mm[:, 2]
    u = fx_px * p_camera_mm[:, 0] / z + cx_px
    v = fy_px * p_camera_mm[:, 1] / z + cy_px
    return jnp.stack([u, v], axis=-1), z


def pen_angle_deg(
    hand_angle_deg: Float[ArrayLike, "*n"],
    zero_deg: Float[ArrayLike, ""],
    sign: Float[ArrayLike, ""],
) -> Float[Array, "*n"]:
    """The angle φ that turns the pen offset: ``φ = zero + sign·θh`` (paper notes, item 3).

    Robot controllers differ in where the sixth axis reads zero and which way it turns; the
    published data has ``zero = 90``, ``sign = -1``.
    """
    return zero_deg + sign * jnp.asarray(hand_angle_deg)


def pen_offset(
    t_hand_pen_mm: Float[Array, "3"], phi_deg: Float[Array, " n"]
) -> Float[Array, "n 3"]:
    """Pen offset ``x' = Ry(-180)·Rz(φ)·t_p`` in the base frame, eqs. (6)-(7).

    Args:
        t_hand_pen_mm: the pen tip in the hand frame at zero angle, ``(xp, yp, zp)`` in mm.
        phi_deg: the angle φ of each touch in degrees (see :func:`pen_angle_deg`).

    Returns:
        One offset per touch, in mm, in the base frame.
    """
    a = jnp.deg2rad(phi_deg)
    c, s = jnp.cos(a), jnp.sin(a)
    xp, yp, zp = t_hand_pen_mm[0], t_hand_pen_mm[1], t_hand_pen_mm[2]
    # Ry(-180) = diag(-1, 1, -1) applied to Rz(φ)·t_p, written out as eq. (7) does.
    return jnp.stack([-(c * xp - s * yp), s * xp + c * yp, -zp * jnp.ones_like(a)], axis=-1)


def px_to_mm(length_px: Float[ArrayLike, "*s"], ppi: float, scale: float) -> Float[Array, "*s"]:
    """Tablet pixels to millimetres, eq. (9): ``l_mm = l_px · 25.4 / PPI · s``."""
    return jnp.asarray(length_px) * (MM_PER_INCH / ppi * scale)


def mm_per_tablet_px(ppi: float, scale: float) -> float:
    """Size of one tablet pixel in mm, eq. (9); Python float so it can be a static constant."""
    return MM_PER_INCH / float(ppi) * float(scale)
