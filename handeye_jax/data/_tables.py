"""Dataset files: ``handeye-jax.dataset/1`` and ``/2`` (TOML; mm, deg, px).

Version 2 (several captures, touches referencing their landmark, an optional hand height)::

    format = "handeye-jax.dataset/2"
    name = "myrig"

    [camera]                        # pinhole intrinsics, px
    fx = 617.7
    fy = 617.7
    cx = 316.5
    cy = 242.3
    distortion = [0.0, 0.0, 0.0, 0.0, 0.0]   # optional: plumb_bob k1 k2 p1 p2 k3

    [tablet]                        # eq. (9): one tablet px is 25.4 / ppi * scale mm
    ppi = 267.0
    scale = 2.0

    [hand_angle]                    # phi = zero + sign * hand_angle, deg
    zero = 90.0
    sign = -1

    [search]                        # optional: name = [lo, hi] overrides a search range
    xt = [100.0, 250.0]

    [[landmarks]]                   # one per landmark drawn on the tablet
    tablet_px = [400.0, 150.0]      # px; no two alike

    [[captures]]                    # one per picture
    hand_position = [320.0, -70.0, 290.0]   # mm, base frame, hand pointing down (eq. 1)
    hand_angle = 90.0                       # deg, the controller's reading at the capture
    landmarks = [0, 1, 2]                   # the landmarks this picture sees
    image_px = [[119.0, 105.0], [339.0, 108.0], [558.0, 109.0]]   # px, one per landmark seen
    depth = [168.2, 168.6, 167.7]                                 # mm, one per landmark seen

    [[touches]]                     # one per touch
    landmark = 0                    # the landmark touched
    hand_xy = [289.0, 1.0]          # mm, base frame
    hand_z = 105.0                  # optional: mm, as the controller reports it
    hand_angle = 0.0                # deg
    touch_error_px = [-3.0, 1.0]    # touched minus drawn position, tablet px

Version 1 (the paper's single capture) holds one ``[capture] hand_position`` and per landmark
``tablet_px, image_px, depth, hand_xy, hand_angle, touch_error_px``; it loads as one capture at
the hand angle where ``φ = 0`` (``−zero·sign``), its landmarks touched in order. Each field is
described once, in the tables below, and read and written from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._core import (
    MAX_DEG,
    MAX_MM,
    MAX_PX,
    Reader,
    join_key,
)

FORMAT_V1 = "handeye-jax.dataset/1"
FORMAT_V2 = "handeye-jax.dataset/2"
FORMATS = {FORMAT_V1: 1, FORMAT_V2: 2}
#: Most captures in a dataset.
MAX_CAPTURES = 1_000


@dataclass(frozen=True)
class Field:
    """One number or vector of a dataset file.

    Attributes:
        key: its name in the file.
        n: 0 for a number, else the vector's length.
        unit: ``"px"``, ``"mm"``, ``"deg"`` or ``"1"``.
        limit: the largest magnitude allowed.
        positive: must be > 0.
        minimum: must be at least this.
        optional: may be absent.
    """

    key: str
    n: int
    unit: str
    limit: float | None
    positive: bool = False
    minimum: float | None = None
    optional: bool = False

    def read(self, r: Reader, value: Any, where: str):
        if self.n == 0:
            unit = "" if self.unit == "1" else self.unit
            return r.number(value, where, self.positive, self.limit, self.minimum, unit)
        return r.vector(value, where, self.n, self.limit)


# The schema: every field of every table, once.
#: Largest magnitude of a distortion coefficient: real lenses' are below 1 (fisheyes' ~ 10).
MAX_DISTORTION = 100.0
CAMERA = (
    Field("fx", 0, "px", MAX_PX, positive=True, minimum=1),
    Field("fy", 0, "px", MAX_PX, positive=True, minimum=1),
    Field("cx", 0, "px", MAX_PX),
    Field("cy", 0, "px", MAX_PX),
    # plumb_bob (Brown–Conrady) k1, k2, p1, p2, k3 in OpenCV's order; absent: none.
    Field("distortion", 5, "1", MAX_DISTORTION, optional=True),
)
TABLET = (
    Field("ppi", 0, "1", 1e5, positive=True, minimum=1),
    Field("scale", 0, "1", 100, positive=True, minimum=0.01),
)
HAND_ANGLE = (Field("zero", 0, "deg", MAX_DEG), Field("sign", 0, "1", None))
LANDMARK_V1 = (
    Field("tablet_px", 2, "px", MAX_PX),
    Field("image_px", 2, "px", MAX_PX),
    Field("depth", 0, "mm", MAX_MM, positive=True),
    Field("hand_xy", 2, "mm", MAX_MM),
    Field("hand_angle", 0, "deg", MAX_DEG),
    Field("touch_error_px", 2, "px", MAX_PX),
)
CAPTURE_V1 = (Field("hand_position", 3, "mm", MAX_MM),)
LANDMARK_V2 = (Field("tablet_px", 2, "px", MAX_PX),)
CAPTURE_V2 = (Field("hand_position", 3, "mm", MAX_MM), Field("hand_angle", 0, "deg", MAX_DEG))
CAPTURE_VIEWS = (Field("image_px", 2, "px", MAX_PX), Field("depth", 0, "mm", MAX_MM, True))
TOUCH_V2 = (
    Field("hand_xy", 2, "mm", MAX_MM),
    Field("hand_z", 0, "mm", MAX_MM, optional=True),
    Field("hand_angle", 0, "deg", MAX_DEG),
    Field("touch_error_px", 2, "px", MAX_PX),
)
_TOP_V1 = ("format", "name", "camera", "capture", "tablet", "hand_angle", "search", "landmarks")
_TOP_V2 = ("format", "name", "camera", "tablet", "hand_angle", "search", "landmarks", "captures",
           "touches")  # fmt: skip


def _keys(fields: tuple[Field, ...]) -> tuple[str, ...]:
    return tuple(f.key for f in fields)


def _optional(fields: tuple[Field, ...]) -> tuple[str, ...]:
    return tuple(f.key for f in fields if f.optional)


def _read_table(r: Reader, value: Any, where: str, fields: tuple[Field, ...],
                extra: tuple[str, ...] = ()) -> dict[str, Any]:  # fmt: skip
    """The fields of a table, each read and checked; ``extra`` keys are allowed, not read."""
    table = r.table(value, where, (*_keys(fields), *extra), (*_optional(fields), *extra))
    return {f.key: f.read(r, table[f.key], join_key(where, f.key))
            for f in fields if f.key in table}  # fmt: skip


def _write_table(fields: tuple[Field, ...], values: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for f in fields:
        v = values.get(f.key)
        if v is None or (f.optional and f.n == 0 and math.isnan(float(v))):
            continue
        out[f.key] = float(v) if f.n == 0 else [float(x) for x in np.asarray(v).reshape(-1)]
    return out
