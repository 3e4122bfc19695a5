"""Named frames from a fitted model: :func:`compute_frames`.

:class:`~handeye_jax.Frames` itself is NumPy only (``handeye_jax.robot._frames``); this module
is the JAX side that evaluates a model's ``camera_mount()``, ``tablet_pose()`` and ``t_hand_pen()``.
"""

from __future__ import annotations

from collections.abc import Mapping

import jax
import numpy as np
from jaxtyping import ArrayLike, Float

from .._jax import in_float64
from ..models import AbstractCorrection, AbstractModel, Rig
from ..robot import Affine, Frames

#: The components no model determines: the hand points down at the capture and at every touch
#: and the objective compares x and y only (section 3.5), so a z never enters it. The models
#: fill them with 0; the frames say "undetermined" instead.
UNDETERMINED = ("t_hand_camera_mm.z", "t_base_tablet_mm.z", "t_hand_pen_mm.z")


def capture_hand_angle_deg(rig: Rig) -> float:
    """The hand angle θc at the rig's capture: given, or the one at which φ = 0 (eq. 1)."""
    if rig.capture_hand_angle_deg is not None:
        return float(rig.capture_hand_angle_deg)
    return float(-rig.angle_zero_deg * rig.angle_sign)


@jax.jit
def _mount_pose_pen(model: AbstractModel):
    # One compiled program: evaluated op by op, the first call took about 1.5 s.
    return model.camera_mount(), model.tablet_pose(), model.t_hand_pen()


@in_float64
def compute_frames(
    model: AbstractModel,
    rig: Rig,
    correction: AbstractCorrection | None = None,
    centres_mm: Float[ArrayLike, "2 2"] | None = None,
    *,
    known: Mapping[str, float] | None = None,
    pen_minus_camera_z_mm: float | None = None,
    deploy_stage: int = 2,
    distortion: tuple[float, float, float, float, float] | None = None,
) -> Frames:
    """The frames of a fitted model, as plain numbers.

    Args:
        model: the fitted stage-1 model.
        rig: the rig it was fitted on (intrinsics, capture position, hand-angle convention).
        correction: the fitted stage-2 correction; ``None`` gives identity maps.
        centres_mm: the correction's centres (rows: A1, A2), mm.
        known: values, mm, for components the data leaves undetermined but that are known
            otherwise (a measured camera height, a synthetic twin's truth), by name, e.g.
            ``{"t_hand_camera_mm.z": 12.0}``.
        pen_minus_camera_z_mm: ``z_p − z_c``, mm, when the hand's heights at the touches
            determined it (see :class:`~handeye_jax.HeightOffsets`).
        deploy_stage: the stage the calibration chose to deploy (1 or 2).
        distortion: the lens's plumb_bob ``(k1, k2, p1, p2, k3)`` (the dataset's camera), or
            ``None``.
    """
    known = dict(known or {})
    unknown = sorted(set(known) - set(UNDETERMINED))
    if unknown:
        raise ValueError(f"known: {unknown} are not undetermined components {UNDETERMINED}")
    (R_hc, t_hc), (R_bt, t_bt), t_hp = _mount_pose_pen(model)
    t = {"t_hand_camera_mm": t_hc, "t_base_tablet_mm": t_bt, "t_hand_pen_mm": t_hp}
    t = {k: np.array(v, dtype=np.float64) for k, v in t.items()}
    for name in UNDETERMINED:
        vector, axis = name.split(".")
        t[vector]["xyz".index(axis)] = known.get(name, np.nan)
    if correction is None:
        A1 = A2 = Affine()
        centres = np.zeros((2, 2))
    else:
        p = correction.to_dict()
        A1, A2 = (Affine(p[f"X{i}"], p[f"Y{i}"], p[f"theta{i}"], p[f"Sx{i}"], p[f"Sy{i}"])
                  for i in (1, 2))  # fmt: skip
        centres = np.asarray(centres_mm, dtype=np.float64)
    return Frames(
        R_hand_camera=np.asarray(R_hc, dtype=np.float64),
        t_hand_camera_mm=t["t_hand_camera_mm"],
        R_base_tablet=np.asarray(R_bt, dtype=np.float64),
        t_base_tablet_mm=t["t_base_tablet_mm"],
        t_hand_pen_mm=t["t_hand_pen_mm"],
        fx_px=float(rig.fx_px), fy_px=float(rig.fy_px),
        cx_px=float(rig.cx_px), cy_px=float(rig.cy_px),
        hand_angle_zero_deg=float(rig.angle_zero_deg),
        hand_angle_sign=int(rig.angle_sign),
        capture_position_mm=np.asarray(rig.capture_position_mm, dtype=np.float64),
        capture_hand_angle_deg=capture_hand_angle_deg(rig),
        A1=A1, A2=A2, centres_mm=centres,
        undetermined=tuple(n for n in UNDETERMINED if n not in known),
        model=getattr(model, "name", ""),
        pen_minus_camera_z_mm=pen_minus_camera_z_mm,
        deploy_stage=deploy_stage,
        distortion=distortion,
    )  # fmt: skip
