"""A dataset's hand poses set from the robot's flange poses (:mod:`._poses`): each capture's
``hand_position`` and ``hand_angle``, each touch's ``hand_xy``, ``hand_z`` and ``hand_angle``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._core import InputError
from ._dataset import Capture, Dataset
from ._poses import MAX_TILT_DEG, TILT_WARN_DEG, ToolPose, hand_angle_from_phi


@dataclass(frozen=True)
class PoseReport:
    """What :func:`apply_poses` did: which rows it set and how far each tool was tilted.

    Attributes:
        captures, touches: the indices set.
        tilts: ``(kind, index, tilt deg)`` of every pose, in the CSV's order.
    """

    captures: tuple[int, ...]
    touches: tuple[int, ...]
    tilts: tuple[tuple[str, int, float], ...]

    @property
    def largest_tilt(self) -> tuple[str, int, float]:
        return max(self.tilts, key=lambda t: t[2])

    def tilted(self, above_deg: float = TILT_WARN_DEG) -> list[tuple[str, int, float]]:
        """The poses tilted more than ``above_deg`` from vertical."""
        return [t for t in self.tilts if t[2] > above_deg]

    def warning(self, above_deg: float = TILT_WARN_DEG) -> str | None:
        """A one-line warning naming the tilted poses, or ``None``."""
        tilted = self.tilted(above_deg)
        if not tilted:
            return None
        names = ", ".join(f"{k} {i} ({t:.2f} deg)" for k, i, t in tilted[:5])
        more = f" and {len(tilted) - 5} more" if len(tilted) > 5 else ""
        kind, index, tilt = self.largest_tilt
        return (f"{len(tilted)} of {len(self.tilts)} poses tilted more than {above_deg:g} deg "
                f"from vertical: {names}{more}. The fit takes the tool as vertical; a tilt of "
                f"{tilt:.2f} deg moves a point 150 mm below the flange by "
                f"{150 * np.tan(np.radians(tilt)):.2f} mm sideways: command the tool vertical")


def apply_poses(
    ds: Dataset,
    poses: list[ToolPose],
    *,
    max_tilt_deg: float = MAX_TILT_DEG,
    path: str | Path | None = None,
) -> tuple[Dataset, PoseReport]:
    """``ds`` with the hand poses of ``poses`` (flange poses in the base frame, mm).

    A capture gets ``hand_position`` (the flange's origin) and ``hand_angle``; a touch
    ``hand_xy``, ``hand_z`` and ``hand_angle``. The angle is ``θ = sign·(φ − zero)`` under the
    dataset's convention, within ±180° of the row's previous value.

    Args:
        ds: a version-2 dataset.
        poses: rows of a poses CSV (:func:`~handeye_jax.read_poses_csv`).
        max_tilt_deg: refuse a pose whose tool axis is further than this from vertical, deg.
        path: the poses file, for messages.

    Raises:
        InputError: a version-1 dataset, an index the dataset does not have, a tilted tool.
    """
    if ds.version == 1:
        raise InputError(ds.source, "format", "is version 1: convert it first (handeye-jax "
                         "convert) to set its hand poses from flange poses")  # fmt: skip
    captures = list(ds.captures)
    hand_xy, hand_z = ds.hand_xy_mm.copy(), ds.hand_z_mm.copy()
    angle = ds.hand_angle_deg.copy()
    zero, sign = ds.hand_angle_zero_deg, ds.hand_angle_sign
    done: dict[str, list[int]] = {"capture": [], "touch": []}
    tilts = []
    for p in poses:
        where = f"line {p.line}"
        count = len(captures) if p.kind == "capture" else ds.n_touches
        if p.index >= count:
            raise InputError(path, f"{where}.index", f"{p.kind} {p.index}: the dataset has "
                             f"{count} {p.kind}s (0 to {count - 1})")  # fmt: skip
        tilt = p.tilt_deg
        if tilt > max_tilt_deg:
            raise InputError(path, where, f"the tool of {p.kind} {p.index} is {tilt:.2f} deg "
                             f"from vertical (at most {max_tilt_deg:g}; tilt 180 is a frame "
                             "whose z points up, 90 one whose x is the tool axis): give "
                             "tool0's pose with the tool pointing straight down")  # fmt: skip
        tilts.append((p.kind, p.index, tilt))
        t = p.t_base_tool_mm
        if p.kind == "capture":
            c = captures[p.index]
            theta = hand_angle_from_phi(p.phi_deg, zero, sign, c.hand_angle_deg)
            captures[p.index] = Capture(t, theta, c.landmarks, c.image_px, c.depth_mm)
        else:
            hand_xy[p.index], hand_z[p.index] = t[:2], t[2]
            angle[p.index] = hand_angle_from_phi(p.phi_deg, zero, sign, angle[p.index])
        done[p.kind].append(p.index)
    new = ds.replace(captures=captures, hand_xy_mm=hand_xy, hand_z_mm=hand_z,
                     hand_angle_deg=angle)  # fmt: skip
    return new, PoseReport(tuple(done["capture"]), tuple(done["touch"]), tuple(tilts))


__all__ = ["PoseReport", "apply_poses"]
