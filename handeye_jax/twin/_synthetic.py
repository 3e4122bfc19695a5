"""Exact data from known parameters: run a model's chain backwards.

Given a model (the truth), a rig and where the landmarks are drawn, this computes what the
camera would see (``image_px``, depth) and where the hand must be for the pen to touch each
landmark, optionally off by a given touch error. With no noise, the model that made the data
fits it with F = 0; the tests use this to check that calibration recovers the truth.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import geometry as geo
from .._jax import in_float64
from ..data import Camera, Capture, Dataset
from ..models import AbstractModel, Rig


@in_float64
def synthesize_dataset(
    truth: AbstractModel,
    rig: Rig,
    tablet_px: np.ndarray,
    hand_angle_deg: np.ndarray,
    *,
    ppi: float = 267.0,
    scale: float = 2.0,
    touch_error_px: np.ndarray | None = None,
    tablet_height_mm: float = 120.0,
    camera_z_mm: float = 0.0,
    name: str = "synthetic",
    search: dict[str, tuple[float, float]] | None = None,
) -> Dataset:
    """A noise-free dataset that ``truth`` explains exactly.

    Args:
        truth: the model whose parameters generate the data.
        rig: intrinsics, capture position (mm) and hand-angle convention.
        tablet_px: where the landmarks are drawn, tablet px, shape (n, 2).
        hand_angle_deg: the hand angle θh of each touch, deg, shape (n,).
        ppi, scale: the tablet's pixel density and display scale (eq. 9).
        touch_error_px: where the pen touched relative to each landmark, tablet px; the hand
            positions include it, and the dataset records it, so F stays 0.
        tablet_height_mm: height of the tablet surface in the base frame, mm. It does not
            enter the objective (x-y only) but sets the depths the camera sees.
        camera_z_mm: the camera's offset along the hand's z axis, mm (``zc``; the models
            leave it out because it never enters x-y).
        name: the dataset's name.
        search: ``[search]`` overrides to record in the dataset.
    """
    tablet_px = np.asarray(tablet_px, dtype=float)
    n = tablet_px.shape[0]
    touch_px = np.zeros((n, 2)) if touch_error_px is None else np.asarray(touch_error_px, float)
    mm = geo.mm_per_tablet_px(ppi, scale)

    p_camera = tablet_to_camera(
        truth, rig, tablet_px * mm, tablet_height_mm=tablet_height_mm, camera_z_mm=camera_z_mm
    )
    image_px, depth_mm = geo.project(p_camera, rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px)

    touched = truth.tablet_to_base(jnp.asarray((tablet_px + touch_px) * mm))[:, :2]
    offset = truth.pen_offset(rig.phi_deg(jnp.asarray(hand_angle_deg, dtype=float)))[:, :2]
    hand_xy = touched - offset

    angle = rig.capture_hand_angle_deg  # None: the paper's capture, at φ = 0
    return Dataset(
        name=name,
        camera=Camera(float(rig.fx_px), float(rig.fy_px), float(rig.cx_px), float(rig.cy_px)),
        capture_position_mm=np.asarray(rig.capture_position_mm, dtype=float),
        capture_hand_angle_deg=None if angle is None else float(angle),
        tablet_ppi=float(ppi),
        tablet_scale=float(scale),
        hand_angle_zero_deg=float(rig.angle_zero_deg),
        hand_angle_sign=int(rig.angle_sign),
        search=dict(search or {}),
        tablet_px=tablet_px,
        image_px=np.asarray(image_px, dtype=float),
        depth_mm=np.asarray(depth_mm, dtype=float),
        hand_xy_mm=np.asarray(hand_xy, dtype=float),
        hand_angle_deg=np.asarray(hand_angle_deg, dtype=float),
        touch_error_px=touch_px,
    )


@in_float64
def synthesize_captures(
    truth: AbstractModel,
    rig: Rig,
    tablet_px: np.ndarray,
    hand_angle_deg: np.ndarray,
    capture_poses: list[tuple[np.ndarray, float]],
    *,
    ppi: float = 267.0,
    scale: float = 2.0,
    touch_error_px: np.ndarray | None = None,
    tablet_height_mm: float = 120.0,
    camera_z_mm: float = 0.0,
    pen_z_mm: float | None = None,
    name: str = "synthetic",
    search: dict[str, tuple[float, float]] | None = None,
) -> Dataset:
    """A noise-free dataset from several captures that ``truth`` explains exactly (version 2).

    Every capture sees every landmark; every landmark is touched once, in order.

    Args:
        truth, rig, tablet_px, hand_angle_deg, ppi, scale, touch_error_px, tablet_height_mm,
            camera_z_mm, name, search: as for :func:`synthesize_dataset` (the rig's capture
            pose is not used: ``capture_poses`` gives them).
        capture_poses: each capture's hand position (mm, ``(3,)``) and hand angle θc (deg);
            the hand points down turned by ``φc = zero + sign·θc``.
        pen_z_mm: the pen tip's offset along the hand's z axis, ``zp``, mm; given, each touch
            records the hand's height (the pen tip on the tablet surface), else none does.
    """
    tablet_px = np.asarray(tablet_px, dtype=float)
    n = tablet_px.shape[0]
    touch_px = np.zeros((n, 2)) if touch_error_px is None else np.asarray(touch_error_px, float)
    mm = geo.mm_per_tablet_px(ppi, scale)
    captures = []
    for position, angle in capture_poses:
        rig_c = capture_rig(rig, position, angle)
        p_camera = tablet_to_camera(
            truth, rig_c, tablet_px * mm, tablet_height_mm=tablet_height_mm, camera_z_mm=camera_z_mm
        )
        image_px, depth_mm = geo.project(p_camera, rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px)
        captures.append(Capture(np.asarray(position, float), float(angle), np.arange(n),
                                np.asarray(image_px), np.asarray(depth_mm)))  # fmt: skip
    touched = truth.tablet_to_base(jnp.asarray((tablet_px + touch_px) * mm))
    offset = truth.pen_offset(rig.phi_deg(jnp.asarray(hand_angle_deg, dtype=float)))[:, :2]
    hand_xy = touched[:, :2] - offset
    hand_z = np.full(n, np.nan)
    if pen_z_mm is not None:  # the pen tip, zp below the hand, on the display surface
        hand_z = np.asarray(touched[:, 2]) + tablet_height_mm + float(pen_z_mm)
    return Dataset(
        name=name,
        camera=Camera(float(rig.fx_px), float(rig.fy_px), float(rig.cx_px), float(rig.cy_px)),
        tablet_ppi=float(ppi), tablet_scale=float(scale),
        hand_angle_zero_deg=float(rig.angle_zero_deg), hand_angle_sign=int(rig.angle_sign),
        search=dict(search or {}), tablet_px=tablet_px, captures=captures,
        hand_xy_mm=np.asarray(hand_xy, dtype=float), hand_z_mm=hand_z,
        hand_angle_deg=np.asarray(hand_angle_deg, dtype=float), touch_error_px=touch_px,
        version=2,
    )  # fmt: skip


def capture_rig(rig: Rig, position_mm: np.ndarray, hand_angle_deg: float) -> Rig:
    """``rig`` with another capture pose: hand position (mm) and hand angle θc (deg)."""
    return Rig(rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px, np.asarray(position_mm, float),
               rig.angle_zero_deg, rig.angle_sign, hand_angle_deg)  # fmt: skip


def tablet_to_camera(
    truth: AbstractModel,
    rig: Rig,
    tablet_mm: Float[ArrayLike, "n 2"],
    *,
    tablet_height_mm: float = 120.0,
    camera_z_mm: float = 0.0,
) -> Float[Array, "n 3"]:
    """Points on the tablet display, mm in the tablet frame, to the camera frame at capture, mm.

    The chain of eq. (5) run backwards: tablet → base (lifted by ``tablet_height_mm``) → hand
    at the capture pose → camera (whose mount is ``truth``'s, shifted by ``camera_z_mm`` along
    the hand's z axis). Call inside :func:`handeye_jax.float64` for float64.
    """
    p_base = truth.tablet_to_base(jnp.asarray(tablet_mm, dtype=float))
    p_base = p_base.at[:, 2].add(tablet_height_mm)
    return base_to_camera(truth, rig, p_base, camera_z_mm=camera_z_mm)


def base_to_camera(
    truth: AbstractModel, rig: Rig, p_base_mm: Float[ArrayLike, "n 3"], *, camera_z_mm: float = 0.0
) -> Float[Array, "n 3"]:
    """Points in the base frame, mm, to the camera frame at ``rig``'s capture pose, mm (the
    camera mount ``truth``'s, shifted by ``camera_z_mm`` along the hand's z axis)."""
    R_bh, t_bh = rig.T_base_hand_capture()
    R_hc, t_hc = truth.camera_mount()
    t_hc = t_hc.at[2].add(camera_z_mm)
    p_hand = (jnp.asarray(p_base_mm, dtype=float) - t_bh) @ R_bh
    return (p_hand - t_hc) @ R_hc


@in_float64
def seen_from(
    truth: AbstractModel,
    rig: Rig,
    p_base_mm: Float[ArrayLike, "n 3"],
    position_mm: Float[ArrayLike, "3"],
    hand_angle_deg: float,
    *,
    camera_z_mm: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Where base-frame points (mm) appear in a picture taken from a capture pose (hand
    position mm, hand angle θc deg): ``(image_px (n, 2), depth_mm (n,))``."""
    p = base_to_camera(truth, capture_rig(rig, position_mm, hand_angle_deg), p_base_mm,
                       camera_z_mm=camera_z_mm)  # fmt: skip
    uv, z = geo.project(p, rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px)
    return np.asarray(uv), np.asarray(z)


@in_float64
def true_command(
    truth: AbstractModel,
    rig: Rig,
    p_base_mm: Float[ArrayLike, "n 3"],
    hand_angle_deg: Float[ArrayLike, " n"],
    *,
    pen_z_mm: float = 0.0,
) -> np.ndarray:
    """The hand position ``(x, y, z)``, mm, that puts the pen tip (``truth``'s, ``pen_z_mm``
    along the hand's z) on base-frame points at hand angles θh (deg): ``(n, 3)``."""
    p = jnp.asarray(p_base_mm, dtype=float)
    offset = truth.pen_offset(rig.phi_deg(jnp.asarray(hand_angle_deg, dtype=float)))
    return np.asarray(jnp.concatenate(
        [p[:, :2] - offset[:, :2], p[:, 2:] + pen_z_mm], axis=1))  # fmt: skip
