"""The hand-command chain in NumPy alone: eqs. (4), (5), (7), (8) and (25).

The same chain as :func:`handeye_jax.models.hand_command`, for a robot PC: no JAX, vectorised
over points. ``handeye-jax export --format python`` copies this module's classes and functions
verbatim into the file it writes, so it imports nothing but NumPy (and the standard library).

The hand points down at the capture and at every touch (eq. 1): ``R_base_hand = Ry(180)·Rz(φ)``,
whose x-y block is ``[[-cos φ, sin φ], [sin φ, cos φ]]`` and whose third column is
``(0, 0, -1)``. The x and y of every point therefore never depend on a z (of the camera, the
pen or the tablet); these functions never read one. Heights need only ``z_p − z_c``
(:func:`image_to_base_z`), which touches with the hand's heights determine.
Lengths in mm, angles in degrees, image coordinates in px.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


def sincos_deg(angle_deg):
    """``(sin, cos)`` of angles in degrees; exact at multiples of 90° (``Ry(180)`` is exact)."""
    a = np.asarray(angle_deg, dtype=np.float64)
    k = np.round(a / 90.0)
    r = np.deg2rad(a - 90.0 * k)
    s, c = np.sin(r), np.cos(r)
    q = np.mod(k, 4.0)
    odd = (q == 1.0) | (q == 3.0)
    sin = np.where(odd, c, s) * np.where(q >= 2.0, -1.0, 1.0)
    cos = np.where(odd, s, c) * np.where((q == 1.0) | (q == 2.0), -1.0, 1.0)
    return sin, cos


class Chain(NamedTuple):
    """The fitted numbers the chain reads: the camera, its mount, the pen and the stage-2
    correction (mm, deg, px). Of the two translations only x and y are read."""

    #: ``(fx, fy, cx, cy)``, px.
    camera_px: tuple[float, float, float, float]
    #: the camera's optical frame in the hand frame, (3, 3).
    R_hand_camera: np.ndarray
    #: the camera's origin in the hand frame, mm, (3,) or its (x, y).
    t_hand_camera_mm: np.ndarray
    #: the pen tip in the hand frame, mm, (3,) or its (x, y).
    t_hand_pen_mm: np.ndarray
    #: stage 2's first and second maps, eq. (24): ``(X mm, Y mm, θ deg, Sx, Sy)`` each.
    A1: tuple[float, float, float, float, float]
    A2: tuple[float, float, float, float, float]
    #: their centres of rotation, mm, (2, 2): rows A1, A2.
    centres_mm: np.ndarray


def _camera_point(chain, image_px, depth_mm):
    """Back-projected camera-frame ``(x, y, z = depth)`` of image points (eq. 4), mm, and the
    mount's rotation, as float64 arrays: what the x-y and z chains both start from."""
    fx, fy, cx, cy = chain.camera_px
    d = np.asarray(depth_mm, dtype=np.float64)
    uv = np.asarray(image_px, dtype=np.float64)
    return (d * (uv[:, 0] - cx) / fx, d * (uv[:, 1] - cy) / fy, d,
            np.asarray(chain.R_hand_camera, dtype=np.float64))  # fmt: skip


def image_to_base_xy(chain, image_px, depth_mm, capture_mm, capture_phi_deg):
    """``(x, y)`` of image points in the base frame, eqs. (4)-(5), mm, shape (n, 2).

    Args:
        chain: the fitted numbers (:class:`Chain`); the camera's are read.
        image_px: ``(u, v)`` of each point, px, shape (n, 2).
        depth_mm: depth along the optical axis, mm, shape (n,).
        capture_mm: hand position at the capture, mm, (3,) or (n, 3); only x and y are read.
        capture_phi_deg: the hand's turn φ at the capture, deg, scalar or (n,).
    """
    p0, p1, d, R = _camera_point(chain, image_px, depth_mm)
    t = np.asarray(chain.t_hand_camera_mm, dtype=np.float64)
    hx = R[0, 0] * p0 + R[0, 1] * p1 + R[0, 2] * d + t[0]
    hy = R[1, 0] * p0 + R[1, 1] * p1 + R[1, 2] * d + t[1]
    s, c = sincos_deg(capture_phi_deg)
    cap = np.asarray(capture_mm, dtype=np.float64)
    return np.stack([-c * hx + s * hy + cap[..., 0], s * hx + c * hy + cap[..., 1]], axis=-1)


def image_to_base_z(chain, image_px, depth_mm, capture_mm):
    """``z`` of image points in the base frame with the camera at ``z_c = 0`` on the hand, mm,
    shape (n,): the capture's height minus the point's height below the hand (the hand
    points down, so its turn φ does not enter). A command's height adds ``z_p − z_c``.

    Args:
        chain, image_px, depth_mm: as for :func:`image_to_base_xy`.
        capture_mm: hand position at the capture, mm, (3,) or (n, 3); only z is read.
    """
    p0, p1, d, R = _camera_point(chain, image_px, depth_mm)
    hz = R[2, 0] * p0 + R[2, 1] * p1 + R[2, 2] * d
    return np.asarray(capture_mm, dtype=np.float64)[..., 2] - hz


def pen_offset_xy(t_hand_pen_mm, phi_deg):
    """``(x, y)`` of the pen offset ``x' = Ry(180)·Rz(φ)·t_p`` in the base frame, eq. (7), mm."""
    s, c = sincos_deg(phi_deg)
    xp, yp = float(t_hand_pen_mm[0]), float(t_hand_pen_mm[1])
    return np.stack([-c * xp + s * yp, s * xp + c * yp], axis=-1)


def affine_about(xy_mm, centre_mm, affine):
    """Eq. (24): scale, rotate about ``centre_mm``, then shift; ``affine = (X, Y, θ, Sx, Sy)``
    in mm, mm, deg, 1, 1."""
    X, Y, theta, Sx, Sy = affine
    s, c = sincos_deg(theta)
    cx, cy = float(centre_mm[0]), float(centre_mm[1])
    a = (xy_mm[:, 0] - cx) * Sx
    b = (xy_mm[:, 1] - cy) * Sy
    return np.stack([c * a - s * b + cx + X, s * a + c * b + cy + Y], axis=-1)


def hand_command_xy(chain, image_px, depth_mm, phi_deg, capture_mm, capture_phi_deg, *, stage=2):
    """Where to send the hand, ``(x, y)`` in mm in the base frame, shape (n, 2).

    Stage 1 is eq. (8), ``x_bi − x'``; stage 2 is eq. (25), ``A2(A1(x_bi) − x')`` with A1
    turning about ``centres_mm[0]`` and A2 about ``centres_mm[1]``.

    Args:
        chain: the fitted numbers (:class:`Chain`).
        image_px, depth_mm, capture_mm, capture_phi_deg: the targets and where they were seen
            from, as for :func:`image_to_base_xy`.
        phi_deg: the hand's turn at each touch, ``φ = zero + sign·θh``, deg, scalar or (n,).
        stage: 1 or 2.
    """
    x_bi = image_to_base_xy(chain, image_px, depth_mm, capture_mm, capture_phi_deg)
    offset = pen_offset_xy(chain.t_hand_pen_mm, phi_deg)
    if stage == 1:
        return x_bi - offset
    a1 = affine_about(x_bi, chain.centres_mm[0], chain.A1)
    return affine_about(a1 - offset, chain.centres_mm[1], chain.A2)
