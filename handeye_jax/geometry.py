"""Pure, jittable geometry of the paper's transform chain, eqs. (1)-(11).

Frame names follow the jaxlie convention: ``R_a_b`` rotates vectors expressed in frame ``b``
into frame ``a``, and ``t_a_b`` is the origin of ``b`` expressed in ``a``. Frames are the
paper's: ``base`` (Σb), ``hand`` (Σh), ``camera`` (Σc), ``image`` (Σi) and ``tablet`` (Σt).

All angles are in degrees (the paper's unit), all lengths in millimetres, image coordinates in
pixels. Every function is dtype-polymorphic; the public API runs it in float64 (see
:mod:`handeye_jax._jax._x64`).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

MM_PER_INCH = 25.4

# The capture and touch poses point the tool flange straight down: eq. (1)'s Ry(-180).
HAND_DOWN_Y_DEG = -180.0


# Minimax coefficients for sin and cos on [-pi/4, pi/4], from Cephes (sin.c); relative error
# about 1e-16 there.
_SIN_COEFFS = (
    1.58962301576546568060e-10, -2.50507477628578072866e-8, 2.75573136213857245213e-6,
    -1.98412698295895385996e-4, 8.33333333332211858878e-3, -1.66666666666666307295e-1,
)  # fmt: skip
_COS_COEFFS = (
    -1.13585365213876817300e-11, 2.08757008419747316778e-9, -2.75573141792967388112e-7,
    2.48015872888517045348e-5, -1.38888888888730564116e-3, 4.16666666666665929218e-2,
)  # fmt: skip


def _horner(x: Array, coeffs: tuple[float, ...]) -> Array:
    acc = coeffs[0]
    for c in coeffs[1:]:
        acc = acc * x + c
    return acc


@jax.custom_jvp
def _sincos_deg(angle_deg: Float[ArrayLike, "*s"]) -> tuple[Float[Array, "*s"], Float[Array, "*s"]]:
    """``(sin, cos)`` of an angle in degrees, within 3e-16 of the exact values.

    Written as polynomials (exact quadrant reduction in degrees, then Cephes' minimax
    polynomials on [-45°, 45°]) because XLA evaluates these as fused, vectorised arithmetic,
    where float64 ``jnp.sin``/``jnp.cos`` call scalar libm: several times faster on a
    population. Multiples of 90° come out exact (``Ry(-180)`` is exactly ``diag(-1, 1, -1)``).

    The pair is rescaled to unit length. Besides keeping rotations orthonormal to the last
    bit, the square root and division make XLA store each angle's sin and cos once; without
    them it recomputes the polynomials in every fused loop that reads them, and a DE
    generation is slower (``benchmarks/RESULTS.md``, "Figures the code's comments point to").
    """
    a = jnp.asarray(angle_deg)
    k = jnp.round(a * (1.0 / 90.0))
    r = (a - 90.0 * k) * (math.pi / 180.0)
    r2 = r * r
    s = r + r * r2 * _horner(r2, _SIN_COEFFS)
    c = 1.0 - 0.5 * r2 + r2 * r2 * _horner(r2, _COS_COEFFS)
    norm = jnp.sqrt(s * s + c * c)
    s, c = s / norm, c / norm
    q = k - 4.0 * jnp.floor(k * 0.25)  # quadrant 0..3, also for negative k
    odd = (q == 1.0) | (q == 3.0)
    sin = jnp.where(odd, c, s) * jnp.where(q >= 2.0, -1.0, 1.0)
    cos = jnp.where(odd, s, c) * jnp.where((q == 1.0) | (q == 2.0), -1.0, 1.0)
    return sin, cos


@_sincos_deg.defjvp
def _sincos_deg_jvp(primals, tangents):
    # d sin = cos·dθ, d cos = −sin·dθ: exact, and a far smaller graph to differentiate and
    # compile than the polynomial's own derivative (the LM polish compiles 1.5 s faster).
    (angle,), (d_angle,) = primals, tangents
    sin, cos = sincos_deg(angle)
    d = jnp.asarray(d_angle) * (math.pi / 180.0)
    return (sin, cos), (cos * d, -sin * d)


# Jitted, so that it is traced once per shape: the chain calls it about 150 times in a
# calibration's programs, and inline it made a fifth of their tracing (its JVP and batched
# forms are cached with it).
sincos_deg = jax.jit(_sincos_deg)


def rot_x(angle_deg: Float[ArrayLike, ""]) -> Float[Array, "3 3"]:
    """Rotation about x by ``angle_deg`` degrees (right-handed)."""
    s, c = sincos_deg(angle_deg)
    one, zero = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack(
        [jnp.stack([one, zero, zero]), jnp.stack([zero, c, -s]), jnp.stack([zero, s, c])]
    )


def rot_y(angle_deg: Float[ArrayLike, ""]) -> Float[Array, "3 3"]:
    """Rotation about y by ``angle_deg`` degrees (right-handed)."""
    s, c = sincos_deg(angle_deg)
    one, zero = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack(
        [jnp.stack([c, zero, s]), jnp.stack([zero, one, zero]), jnp.stack([-s, zero, c])]
    )


def rot_z(angle_deg: Float[ArrayLike, ""]) -> Float[Array, "3 3"]:
    """Rotation about z by ``angle_deg`` degrees (right-handed)."""
    s, c = sincos_deg(angle_deg)
    one, zero = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack(
        [jnp.stack([c, -s, zero]), jnp.stack([s, c, zero]), jnp.stack([zero, zero, one])]
    )


def rot_zyx(
    gamma_deg: Float[ArrayLike, ""], beta_deg: Float[ArrayLike, ""], alpha_deg: Float[ArrayLike, ""]
) -> Float[Array, "3 3"]:
    """``Rz(γ)·Ry(β)·Rx(α)`` in closed form (angles in degrees).

    Equal to ``compose(rot_z(γ), rot_y(β), rot_x(α))``; written out because XLA does not fold
    the products with the zeros and ones of the three factors. The three angles go through
    one :func:`sincos_deg` call, so that a population's sines and cosines form one array.
    """
    s, c = sincos_deg(jnp.stack(jnp.broadcast_arrays(gamma_deg, beta_deg, alpha_deg)))
    (sg, sb, sa), (cg, cb, ca) = s, c
    return jnp.stack(
        [
            jnp.stack([cg * cb, cg * sb * sa - sg * ca, cg * sb * ca + sg * sa]),
            jnp.stack([sg * cb, sg * sb * sa + cg * ca, sg * sb * ca - cg * sa]),
            jnp.stack([-sb, cb * sa, cb * ca]),
        ]
    )


def matmul3(A: Float[Array, "3 k"], B: Float[Array, "k m"]) -> Float[Array, "3 m"]:
    """``A @ B`` for small matrices, as explicit elementwise sums.

    Under ``vmap`` over a population, ``@`` becomes a batched ``dot_general`` of thousands of
    tiny products, which XLA's CPU backend runs one by one; sums of broadcast products fuse
    into a single vectorised loop instead.
    """
    return sum(A[:, k, None] * B[None, k, :] for k in range(A.shape[1]))


def compose(*Rs: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """The product ``R1 @ R2 @ …`` of 3×3 matrices (see :func:`matmul3`)."""
    out = Rs[0]
    for R in Rs[1:]:
        out = matmul3(out, R)
    return out


def htm(R: Float[Array, "3 3"], t: Float[Array, "3"]) -> Float[Array, "4 4"]:
    """Homogeneous transform matrix ``[[R, t], [0, 1]]``."""
    bottom = jnp.array([0.0, 0.0, 0.0, 1.0], dtype=R.dtype)
    return jnp.concatenate([jnp.concatenate([R, t[:, None]], axis=1), bottom[None]], axis=0)


def transform_points(
    R_a_b: Float[Array, "3 k"], t_a_b: Float[Array, "3"], p_b: Float[Array, "n k"]
) -> Float[Array, "n 3"]:
    """Map points ``p_b`` (rows, expressed in frame b) into frame a: ``R_a_b p + t_a_b``."""
    return rotate_vectors(R_a_b, p_b) + t_a_b


def rotate_vectors(R_a_b: Float[Array, "m k"], v_b: Float[Array, "n k"]) -> Float[Array, "n m"]:
    """Rotate direction vectors (rows) from frame b into frame a: ``R_a_b v``.

    ``R_a_b`` may be a block of a rotation, e.g. its first two columns for vectors in a plane.
    """
    return sum(v_b[:, k, None] * R_a_b[None, :, k] for k in range(R_a_b.shape[1]))


def R_base_hand_down() -> Float[Array, "3 3"]:
    """Orientation of the hand at the capture pose, eq. (1): ``Ry(-180)``."""
    return rot_y(HAND_DOWN_Y_DEG)


def hand_to_base(
    p_hand_mm: Float[Array, "n 3"], phi_deg: Float[Array, " n"], t_base_hand_mm: Float[Array, "n 3"]
) -> Float[Array, "n 3"]:
    """Points in the hand frame to the base frame with the hand pointing down and turned by φ:
    ``Ry(-180)·Rz(φ)·p + t``, eq. (1) at any hand angle (one pose per point).

    Args:
        p_hand_mm: the points in the hand frame, mm.
        phi_deg: the hand's turn ``φ = zero + sign·θh`` of each point's pose, deg.
        t_base_hand_mm: the hand position of each point's pose, mm.
    """
    s, c = sincos_deg(phi_deg)
    x, y, z = p_hand_mm[:, 0], p_hand_mm[:, 1], p_hand_mm[:, 2]
    # Ry(-180) = diag(-1, 1, -1) after Rz(φ), as eq. (7) writes it for the pen.
    return jnp.stack([-(c * x - s * y), s * x + c * y, -z], axis=-1) + t_base_hand_mm


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
    s, c = sincos_deg(phi_deg)
    xp, yp, zp = t_hand_pen_mm[0], t_hand_pen_mm[1], t_hand_pen_mm[2]
    # Ry(-180) = diag(-1, 1, -1) applied to Rz(φ)·t_p, written out as eq. (7) does.
    return jnp.stack([-(c * xp - s * yp), s * xp + c * yp, -zp * jnp.ones_like(c)], axis=-1)


def px_to_mm(length_px: Float[ArrayLike, "*s"], ppi: float, scale: float) -> Float[Array, "*s"]:
    """Tablet pixels to millimetres, eq. (9): ``l_mm = l_px · 25.4 / PPI · s``."""
    return jnp.asarray(length_px) * (MM_PER_INCH / ppi * scale)


def mm_per_tablet_px(ppi: float, scale: float) -> float:
    """Size of one tablet pixel in mm, eq. (9); Python float so it can be a static constant."""
    return MM_PER_INCH / float(ppi) * float(scale)
