"""The z offsets the data leaves open, given by the user: :func:`with_heights`.

The hand points down at the capture and at every touch, so the camera's and the pen tip's
offsets along the tool axis (``z_c``, ``z_p``) never enter the fit's x-y terms. With the hand's
heights at the touches the fit determines their difference ``z_p − z_c``
(:attr:`Frames.pen_minus_camera_z_mm`); their common part stays open. A robot's tf tree needs
both, so the user gives one (measured: the camera's optical centre, or the pen's length, along
the flange's z) and the other follows.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ._frames import Frames

CAMERA_Z = "t_hand_camera_mm.z"
PEN_Z = "t_hand_pen_mm.z"


def with_heights(
    frames: Frames, camera_z_mm: float | None = None, pen_z_mm: float | None = None
) -> Frames:
    """``frames`` with the camera's and the pen tip's z (mm, along the hand's z) filled in.

    Args:
        frames: the fitted frames.
        camera_z_mm: the camera's optical centre along the hand's z axis, mm (measured).
        pen_z_mm: the pen tip along the hand's z axis, mm (measured). When the calibration
            determined ``z_p − z_c``, give one of the two: the other follows from it.

    Raises:
        ValueError: both given while ``z_p − z_c`` is determined, a value not finite, or a
            component the frames already determine.
    """
    given = {CAMERA_Z: camera_z_mm, PEN_Z: pen_z_mm}
    given = {k: float(v) for k, v in given.items() if v is not None}
    for name, v in given.items():
        if not math.isfinite(v):
            raise ValueError(f"{name} must be finite (got {v})")
        if name not in frames.undetermined:
            how = "given" if name in frames.given else "determined by the data"
            raise ValueError(f"{name} is already known ({how})")
    d = frames.pen_minus_camera_z_mm
    if d is not None:
        if len(given) == 2:
            raise ValueError(f"give the camera's z or the pen's, not both: the calibration "
                             f"determined z_pen − z_camera = {d:.3f} mm")  # fmt: skip
        if CAMERA_Z in given:
            given[PEN_Z] = given[CAMERA_Z] + d
        elif PEN_Z in given:
            given[CAMERA_Z] = given[PEN_Z] - d
    if not given:
        return frames
    cam, pen = frames.t_hand_camera_mm.copy(), frames.t_hand_pen_mm.copy()
    if CAMERA_Z in given:
        cam[2] = given[CAMERA_Z]
    if PEN_Z in given:
        pen[2] = given[PEN_Z]
    return replace(
        frames, t_hand_camera_mm=cam, t_hand_pen_mm=pen,
        undetermined=tuple(c for c in frames.undetermined if c not in given),
        given=(*frames.given, *(c for c in (CAMERA_Z, PEN_Z) if c in given)),
    )  # fmt: skip


def filled_translations_mm(frames: Frames) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """The camera's, the pen's and the tablet's translations as a format that cannot say
    "unknown" writes them, mm: an undetermined component as 0, except the pen's z when only
    ``z_p − z_c`` is known: then the camera's z is 0 and the pen's ``z_p − z_c``, so that
    their difference, which hand heights use, is right. The flag says whether that was done."""
    cam, pen, tab = (np.nan_to_num(v, nan=0.0) for v in
                     (frames.t_hand_camera_mm, frames.t_hand_pen_mm, frames.t_base_tablet_mm))
    relative = (frames.pen_minus_camera_z_mm is not None and CAMERA_Z in frames.undetermined
                and PEN_Z in frames.undetermined)  # fmt: skip
    if relative:
        pen[2] = frames.pen_minus_camera_z_mm
    return cam, pen, tab, relative


__all__ = ["filled_translations_mm", "with_heights"]
