"""A recalibration's new data against its prior's rig: the same camera intrinsics, tablet and
hand-angle convention, or a change the user declared.

A prior is the posterior of a fit on one rig. Data taken with other intrinsics, another tablet
pixel size or another hand-angle convention move every point of the chain: the prior's
parameters would not describe the new rig and the fit would be quietly wrong. So they are
refused, naming the field and both values, unless the change is deliberate (a re-calibrated
camera): then it is accepted and recorded in the result (``recalibration.rig_changes``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from .._core import InputError
from ._payloads import RigChange

if TYPE_CHECKING:
    from ..data import Dataset
    from ._result import CalibrationResult

#: The option of ``handeye-jax calibrate`` that accepts a change.
ACCEPT_OPTION = "--accept-rig-change"
#: Relative difference below which two values are the same (a float's last bits).
SAME = 1e-12


def _mm_per_px(ppi: float, scale: float) -> float:
    return 25.4 / ppi * scale


def rig_changes(dataset: Dataset, previous: CalibrationResult) -> tuple[RigChange, ...]:
    """How the rig of ``dataset`` differs from the one ``previous`` was fitted on (the
    dataset's field names), empty if in nothing."""
    rig = previous.rig
    pairs = [
        ("camera.fx", float(rig.fx_px), dataset.camera.fx_px, "px"),
        ("camera.fy", float(rig.fy_px), dataset.camera.fy_px, "px"),
        ("camera.cx", float(rig.cx_px), dataset.camera.cx_px, "px"),
        ("camera.cy", float(rig.cy_px), dataset.camera.cy_px, "px"),
        ("hand_angle.zero", float(rig.angle_zero_deg), dataset.hand_angle_zero_deg, "deg"),
        ("hand_angle.sign", float(rig.angle_sign), dataset.hand_angle_sign, ""),
    ]
    old = previous.data
    if old is not None:  # the tablet's pixel size is what the chain sees (eq. 9)
        now = _mm_per_px(dataset.tablet_ppi, dataset.tablet_scale)
        if _differ(_mm_per_px(old.tablet_ppi, old.tablet_scale), now):
            if _differ(old.tablet_scale, dataset.tablet_scale):
                pairs.append(("tablet.scale", old.tablet_scale, dataset.tablet_scale, ""))
            if _differ(old.tablet_ppi, dataset.tablet_ppi):
                pairs.append(("tablet.ppi", old.tablet_ppi, dataset.tablet_ppi, ""))
    return tuple(RigChange(f, float(a), float(b), u) for f, a, b, u in pairs if _differ(a, b))


def _differ(a: float, b: float) -> bool:
    return abs(float(a) - float(b)) > SAME * max(1.0, abs(float(a)), abs(float(b)))


def _value(x: float, unit: str) -> str:
    return f"{x:.10g}{' ' + unit if unit else ''}"


def check_rig(
    dataset: Dataset, previous: CalibrationResult, source: str, accept: bool = False
) -> tuple[RigChange, ...]:
    """The rig changes of :func:`rig_changes`; unless ``accept``, the first one is an
    :class:`InputError` naming the dataset's file, the field and both values.

    Args:
        dataset: the new data.
        previous: the prior's result.
        source: where ``previous`` came from (its file's name), for the message.
        accept: the change is deliberate (e.g. a re-calibrated camera).
    """
    changes = rig_changes(dataset, previous)
    if changes and not accept:
        c = changes[0]
        path = Path(dataset.source) if dataset.source else None
        raise InputError(path, c.name, f"is {_value(c.new, c.unit)}; the prior {source} "
                         f"was fitted with {_value(c.previous, c.unit)}: another rig? A "
                         f"deliberate change (a re-calibrated camera) is accepted with "
                         f"{ACCEPT_OPTION}")  # fmt: skip
    return changes


def change_line(changes: tuple[RigChange, ...]) -> str:
    """The summary's line saying what changed since the prior, accepted."""
    what = "; ".join(f"{c.name} {_value(c.previous, c.unit)} → {_value(c.new, c.unit)}"
                     for c in changes)  # fmt: skip
    return f"the rig changed since the prior, accepted ({ACCEPT_OPTION}): {what}"
