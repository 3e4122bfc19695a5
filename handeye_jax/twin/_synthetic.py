"""Exact data from known parameters: run a model's chain backwards.

Given a model (the truth), a rig and where the landmarks are drawn, this computes what the
camera would see (``image_px``, depth) and where the hand must be for the pen to touch each
landmark, optionally off by a given touch error. With no noise, the model that made the data
fits it with F = 0; the tests use this to check that calibration recovers the truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import geometry as geo
from .._jax import fast_compile, in_float64
from ..data import Camera, Capture, Dataset
from ..models import AbstractModel, Rig


@dataclass(frozen=True)
class Scene:
    """What the data depend on but the twelve-parameter chain leaves out.

    Attributes:
        ppi, scale: the tablet's pixel density and display scale; one tablet px is
            ``25.4 / ppi * scale`` mm (eq. 9).
        tablet_height_mm: height of the tablet surface in the base frame, mm. It does not
            enter the objective (x-y only) but sets the depths the camera sees.
        camera_z_mm: the camera's offset along the hand's z axis, mm (``zc``; the models
            leave it out because it never enters x-y).
        pen_z_mm: the pen tip's offset along the hand's z axis, ``zp``, mm. Given, each touch
            of a dataset with captures records the hand's height (the pen tip on the tablet
            surface); else none does.
    """

    ppi: float = 267.0
    scale: float = 2.0
    tablet_height_mm: float = 120.0
    camera_z_mm: float = 0.0
    pen_z_mm: float | None = None


@in_float64
def synthesize_dataset(
    truth: AbstractModel,
    rig: Rig,
    tablet_px: Float[ArrayLike, "n 2"],
    hand_angle_deg: Float[ArrayLike, " n"],
    *,
    captures: Sequence[tuple[Float[ArrayLike, "3"], float]] | None = None,
    scene: Scene = Scene(),
    touch_error_px: Float[ArrayLike, "n 2"] | None = None,
) -> Dataset:
    """A noise-free dataset that ``truth`` explains exactly, named ``synthetic`` (give it
    another name, or ``[search]`` overrides, with :meth:`~handeye_jax.Dataset.replace`).

    Args:
        truth: the model whose parameters generate the data.
        rig: intrinsics, capture position (mm) and hand-angle convention.
        tablet_px: where the landmarks are drawn, tablet px, shape (n, 2).
        hand_angle_deg: the hand angle θh of each touch, deg, shape (n,).
        captures: ``None``: one capture, from the rig's capture pose (a version-1 dataset).
            Else each capture's hand position (mm, ``(3,)``) and hand angle θc (deg), the hand
            pointing down turned by ``φc = zero + sign·θc``; every capture sees every
            landmark, and every landmark is touched once, in order (version 2).
        scene: what the chain leaves out (:class:`Scene`); its ``pen_z_mm`` needs
            ``captures``.
        touch_error_px: where the pen touched relative to each landmark, tablet px; the hand
            positions include it, and the dataset records it, so F stays 0.
    """
    tablet_px = np.asarray(tablet_px, dtype=float)
    n = tablet_px.shape[0]
    touch_px = np.zeros((n, 2)) if touch_error_px is None else np.asarray(touch_error_px, float)
    mm = geo.mm_per_tablet_px(scene.ppi, scene.scale)
    touched, offset = _touched(truth, rig, (tablet_px + touch_px) * mm,
                               np.asarray(hand_angle_deg, dtype=float))  # fmt: skip
    common = dict(
        name="synthetic",
        camera=Camera(float(rig.fx_px), float(rig.fy_px), float(rig.cx_px), float(rig.cy_px)),
        tablet_ppi=float(scene.ppi), tablet_scale=float(scene.scale),
        hand_angle_zero_deg=float(rig.angle_zero_deg), hand_angle_sign=int(rig.angle_sign),
        search={}, tablet_px=tablet_px,
        hand_xy_mm=np.asarray(touched[:, :2] - offset[:, :2], dtype=float),
        hand_angle_deg=np.asarray(hand_angle_deg, dtype=float), touch_error_px=touch_px,
    )  # fmt: skip
    if captures is None:
        if scene.pen_z_mm is not None:
            raise ValueError("pen_z_mm records the hand's heights, which need captures")
        image_px, depth_mm = _seen(truth, rig, tablet_px * mm, scene)
        angle = rig.capture_hand_angle_deg  # None: the paper's capture, at φ = 0
        return Dataset(
            capture_position_mm=np.asarray(rig.capture_position_mm, dtype=float),
            capture_hand_angle_deg=None if angle is None else float(angle),
            image_px=image_px, depth_mm=depth_mm, **common,
        )  # fmt: skip
    shots = []
    for position, angle in captures:
        image_px, depth_mm = _seen(truth, capture_rig(rig, position, angle), tablet_px * mm, scene)
        shots.append(Capture(np.asarray(position, float), float(angle), np.arange(n), image_px,
                             depth_mm))  # fmt: skip
    hand_z = np.full(n, np.nan)
    if scene.pen_z_mm is not None:  # the pen tip, zp below the hand, on the display surface
        hand_z = np.asarray(touched[:, 2]) + scene.tablet_height_mm + float(scene.pen_z_mm)
    return Dataset(captures=shots, hand_z_mm=hand_z, version=2, **common)


def _seen(truth: AbstractModel, rig: Rig, tablet_mm, scene: Scene) -> tuple[np.ndarray, ...]:
    """What the camera at ``rig``'s capture pose sees of tablet points (mm): image px and
    depths, mm."""
    _, image_px, depth_mm = camera_view(truth, rig, tablet_mm, scene.tablet_height_mm,
                                        scene.camera_z_mm)  # fmt: skip
    return image_px, depth_mm


# The twin's chain runs as compiled programs, not operation by operation: a twin takes a few
# hundred evaluations of it (a rendered picture, two per landmark), and each eager operation
# costs a dispatch, and a compilation per new shape.
@fast_compile
def _touched(truth: AbstractModel, rig: Rig, tablet_mm, hand_angle_deg):
    return truth.tablet_to_base(tablet_mm), truth.pen_offset(rig.phi_deg(hand_angle_deg))


@fast_compile
def _camera_view(truth: AbstractModel, rig: Rig, tablet_mm, tablet_height_mm, camera_z_mm):
    p = tablet_to_camera(truth, rig, tablet_mm, tablet_height_mm=tablet_height_mm,
                         camera_z_mm=camera_z_mm)  # fmt: skip
    return (p, *geo.project(p, rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px))


@in_float64
def camera_view(
    truth: AbstractModel,
    rig: Rig,
    tablet_mm: Float[ArrayLike, "n 2"],
    tablet_height_mm: float,
    camera_z_mm: float,
) -> tuple[Float[np.ndarray, "n 3"], Float[np.ndarray, "n 2"], Float[np.ndarray, " n"]]:
    """Tablet points (mm, tablet frame) seen from ``rig``'s capture pose, in one compiled
    program: ``(camera-frame points mm, image px, depths mm)`` (see :func:`tablet_to_camera`)."""
    out = _camera_view(truth, rig, np.asarray(tablet_mm, dtype=float),
                       np.asarray(tablet_height_mm, dtype=float),
                       np.asarray(camera_z_mm, dtype=float))  # fmt: skip
    return tuple(np.asarray(a, dtype=float) for a in out)


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
    uv, z = _seen_from(truth, capture_rig(rig, position_mm, hand_angle_deg),
                       np.asarray(p_base_mm, dtype=float), np.asarray(camera_z_mm, dtype=float))
    return np.asarray(uv), np.asarray(z)


@fast_compile
def _seen_from(truth: AbstractModel, rig: Rig, p_base_mm, camera_z_mm):
    p = base_to_camera(truth, rig, p_base_mm, camera_z_mm=camera_z_mm)
    return geo.project(p, rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px)


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
    return np.asarray(_command(truth, rig, np.asarray(p_base_mm, dtype=float),
                               np.asarray(hand_angle_deg, dtype=float),
                               np.asarray(pen_z_mm, dtype=float)))  # fmt: skip


@fast_compile
def _command(truth: AbstractModel, rig: Rig, p, hand_angle_deg, pen_z_mm):
    offset = truth.pen_offset(rig.phi_deg(hand_angle_deg))
    return jnp.concatenate([p[:, :2] - offset[:, :2], p[:, 2:] + pen_z_mm], axis=1)
