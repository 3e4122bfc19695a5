"""A twin's hand poses as a robot reports them: the flange (``tool0``) pose of every capture
and touch in the base frame, optionally with the tool tilted a little off vertical."""

from __future__ import annotations

import numpy as np

from ..data import Dataset, ToolPose, rotation_from_rotvec, tool_pose_of_hand


def tool_poses(ds: Dataset, tilt_sigma_deg: float = 0.0, seed: int = 0) -> list[ToolPose]:
    """The flange pose of each capture and touch of ``ds`` (``tool0`` = the hand frame), as
    :func:`~handeye_jax.read_poses_csv` gives them.

    Args:
        ds: a dataset whose touches recorded the hand's height (a multi-capture twin's).
        tilt_sigma_deg: each pose's tool is turned about a horizontal axis by a rotation
            vector whose two components are normal with this σ, deg: the orientation a
            controller reports when the tool is not quite vertical. The flange's position
            and the twin's observations stay the vertical truth's.
        seed: seeds the tilts.
    """
    if not np.isfinite(ds.hand_z_mm).all():
        raise ValueError("every touch needs its hand_z for a flange pose (a multi-capture twin)")
    rng = np.random.default_rng(seed)
    zero, sign = ds.hand_angle_zero_deg, ds.hand_angle_sign
    rows = [("capture", k, c.hand_position_mm, c.hand_angle_deg)
            for k, c in enumerate(ds.captures)]  # fmt: skip
    rows += [("touch", t, [*ds.hand_xy_mm[t], ds.hand_z_mm[t]], ds.hand_angle_deg[t])
             for t in range(ds.n_touches)]  # fmt: skip
    out = []
    for line, (kind, index, position, angle) in enumerate(rows, start=2):
        R, t = tool_pose_of_hand(position, angle, zero, sign)
        tilt = np.radians(rng.normal(0.0, tilt_sigma_deg, 2)) if tilt_sigma_deg else np.zeros(2)
        R = rotation_from_rotvec([tilt[0], tilt[1], 0.0]) @ R
        out.append(ToolPose(kind, index, R, t, line))
    return out


__all__ = ["tool_poses"]
