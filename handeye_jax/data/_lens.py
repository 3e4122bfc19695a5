"""Lens distortion, NumPy only: the Brown–Conrady model with OpenCV's five coefficients.

ROS calls it ``plumb_bob``, OpenCV ``distCoeffs = (k1, k2, p1, p2, k3)``, librealsense
``Brown Conrady``. A lens records the point whose pinhole image is ``(x, y)`` (normalised:
``x = X/Z``, ``y = Y/Z``) at the distorted ``(x_d, y_d)``::

    r² = x² + y²,  radial = 1 + k1·r² + k2·r⁴ + k3·r⁶
    x_d = x·radial + 2·p1·x·y + p2·(r² + 2·x²)
    y_d = y·radial + p1·(r² + 2·y²) + 2·p2·x·y

and the pixel is ``(fx·x_d + cx, fy·y_d + cy)``, as ``cv2.projectPoints`` computes it. The
transform chain back-projects through a pinhole (eq. 4), so every measured image point is
undistorted first: :func:`undistort_px` maps it to the pixel an ideal pinhole camera with the
same ``fx, fy, cx, cy`` would have recorded (``cv2.undistortPoints`` with ``P = K``, iterated
to convergence). The fit, :class:`~handeye_jax.Predictor` and the exported Python module all
call this one function (``export --format python`` copies it verbatim).
"""

from __future__ import annotations

import numpy as np

#: The model's name in ROS's ``camera_info`` and in the toolkit's files.
DISTORTION_MODEL = "plumb_bob"
#: The coefficients, in OpenCV's and ROS's order.
DISTORTION_COEFFICIENTS = ("k1", "k2", "p1", "p2", "k3")


def distort_px(image_px, camera_px, distortion):
    """Where a lens with ``distortion = (k1, k2, p1, p2, k3)`` records pinhole pixels, px.

    Args:
        image_px: ideal (pinhole) pixels ``(u, v)``, shape (n, 2).
        camera_px: ``(fx, fy, cx, cy)``, px.
        distortion: the five coefficients, or ``None`` (no distortion: returned as given).
    """
    uv = np.asarray(image_px, dtype=np.float64)
    if distortion is None:
        return uv
    fx, fy, cx, cy = camera_px
    k1, k2, p1, p2, k3 = (float(c) for c in distortion)
    x, y = (uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy
    r2 = x * x + y * y
    radial = 1.0 + ((k3 * r2 + k2) * r2 + k1) * r2
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([fx * xd + cx, fy * yd + cy], axis=-1)


def undistort_px(image_px, camera_px, distortion):
    """The pinhole pixels of measured (distorted) image points, px, shape (n, 2).

    The fixed-point iteration of ``cv2.undistortPoints``, run until no point moves by more
    than 1e-15 (normalised) or 200 times; a point whose result does not distort back to
    within 1e-9 px of the measurement (a distortion too strong to invert there) is NaN.

    Args:
        image_px: measured pixels ``(u, v)``, shape (n, 2).
        camera_px: ``(fx, fy, cx, cy)``, px.
        distortion: ``(k1, k2, p1, p2, k3)``, or ``None`` (returned as given).
    """
    uv = np.asarray(image_px, dtype=np.float64)
    if distortion is None:
        return uv
    fx, fy, cx, cy = camera_px
    k1, k2, p1, p2, k3 = (float(c) for c in distortion)
    x0, y0 = (uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy
    x, y = x0.copy(), y0.copy()
    for _ in range(200):
        r2 = x * x + y * y
        inverse_radial = 1.0 / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
        dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        x_new, y_new = (x0 - dx) * inverse_radial, (y0 - dy) * inverse_radial
        step = np.max(np.abs(np.concatenate([x_new - x, y_new - y])), initial=0.0)
        x, y = x_new, y_new
        if not step > 1e-15:  # also ends on NaN
            break
    out = np.stack([fx * x + cx, fy * y + cy], axis=-1)
    back = distort_px(out, camera_px, distortion)
    bad = ~(np.abs(back - uv).max(axis=-1, initial=0.0) <= 1e-9)
    out[bad] = np.nan
    return out


__all__ = ["DISTORTION_COEFFICIENTS", "DISTORTION_MODEL", "distort_px", "undistort_px"]
