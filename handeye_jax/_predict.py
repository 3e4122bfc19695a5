"""From observed image points to hand commands: eq. (8) after stage 1, eq. (25) after stage 2.

Also the points CSV (``u,v,depth,hand_angle`` in px, px, mm, deg) that the CLI reads and writes.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._errors import InputError
from ._io import MAX_TEXT_BYTES, csv_rows, read_text
from ._validate import MAX_DEG, MAX_MM, MAX_POINTS, MAX_PX, parse_float

if TYPE_CHECKING:  # the CLI's predict reads the CSV here without JAX
    from jaxtyping import Array, Float

    from ._observations import Rig
    from ._trust import Reach
    from .models import AbstractCorrection, AbstractModel

POINTS_HEADER = ("u", "v", "depth", "hand_angle")
OUTPUT_COLUMNS = ("hand_x", "hand_y", "hand_z")
#: Optional columns: the hand pose each point's picture was taken from (mm, mm, mm, deg).
CAPTURE_COLUMNS = ("capture_x", "capture_y", "capture_z", "capture_angle")
_LIMITS = {"u": MAX_PX, "v": MAX_PX, "depth": MAX_MM, "hand_angle": MAX_DEG}


def hand_command(
    model: AbstractModel,
    rig: Rig,
    image_px: Float[Array, "n 2"],
    depth_mm: Float[Array, " n"],
    hand_angle_deg: Float[Array, " n"],
    correction: AbstractCorrection | None = None,
    centres_mm: Float[Array, "2 2"] | None = None,
    capture_position_mm: Float[Array, "n 3"] | None = None,
    capture_hand_angle_deg: Float[Array, " n"] | None = None,
    pen_minus_camera_mm: Float[Array, ""] | None = None,
) -> Float[Array, "n 2"] | Float[Array, "n 3"]:
    """Where to send the hand, ``(x, y)`` (or ``(x, y, z)``) in mm in the base frame, so the
    pen touches each point.

    A target is any point seen in a picture at its depth, on the tablet or not, taken from any
    capture pose: the hand pointing down, at ``capture_position_mm``, turned by
    ``φc = zero + sign·θc`` (the camera turns with it).

    Args:
        model: a fitted stage-1 model.
        rig: the rig the model was fitted with (intrinsics, capture pose, angle convention).
        image_px: ``(u, v)`` of each target in the captured picture, px.
        depth_mm: depth at each target, mm.
        hand_angle_deg: the hand angle θh the robot will touch with, deg.
        correction: the fitted stage-2 correction; ``None`` gives eq. (8) (stage 1).
        centres_mm: the correction's centres of rotation (rows: A1, A2), fixed at calibration.
        capture_position_mm: the hand position when each target's picture was taken, mm,
            ``(n, 3)``; ``None``: the rig's capture.
        capture_hand_angle_deg: the hand angle θc then, deg, ``(n,)``; ``None``: the rig's.
        pen_minus_camera_mm: the calibration's ``z_p − z_c``, mm; given, the commands carry
            the hand's height as a third column (the affine correction is planar: z has none).
    """
    import jax.numpy as jnp  # here: the points-CSV readers of this module need no JAX

    if capture_position_mm is None and capture_hand_angle_deg is None:
        x_b = model.image_to_base(image_px, depth_mm, rig)
    else:
        n = image_px.shape[0]
        position = rig.capture_position_mm if capture_position_mm is None else (
            capture_position_mm)  # fmt: skip
        phi = (rig.capture_phi_deg() if capture_hand_angle_deg is None
               else rig.phi_deg(capture_hand_angle_deg))  # fmt: skip
        x_b = model.image_to_base(image_px, depth_mm, rig,
                                  jnp.broadcast_to(position, (n, 3)),
                                  jnp.broadcast_to(phi, (n,)))  # fmt: skip
    x_bi = x_b[:, :2]
    offset = model.pen_offset(rig.phi_deg(hand_angle_deg))[:, :2]
    if correction is None:
        xy = x_bi - offset
    else:
        xy = correction.second(correction.first(x_bi, centres_mm[0]) - offset, centres_mm[1])
    if pen_minus_camera_mm is None:
        return xy
    # The hand points down: the pen tip is z_p below the hand, the point z_c below x_b's z.
    return jnp.concatenate([xy, (x_b[:, 2] + pen_minus_camera_mm)[:, None]], axis=1)


def read_points_csv(path: str | Path) -> tuple[list[str], list[list[str]], np.ndarray]:
    """Read a points CSV; returns ``(header, rows, values)`` with ``values`` (n, 4) float64.

    The header must start with ``u,v,depth,hand_angle``; extra columns are kept as they are.
    At most 100,000 points (:data:`~handeye_jax._validate.MAX_POINTS`) in at most 16 MiB.
    """
    path = Path(path)
    _, text = read_text(path, MAX_TEXT_BYTES)  # a BOM, as spreadsheets write, is fine
    # Read no further than one row past the limit: 16 MiB of blank rows holds 16 million.
    lines = list(itertools.islice(csv_rows(text, path), MAX_POINTS + 2))
    if not lines:
        raise InputError(path, "header", f"file is empty; expected {','.join(POINTS_HEADER)}")
    header = [h.strip() for h in lines[0]]
    if tuple(header[:4]) != POINTS_HEADER:
        raise InputError(
            path, "header", f"expected {','.join(POINTS_HEADER)}, got {','.join(header)}"
        )
    twice = sorted({h for h in header if header.count(h) > 1})
    if twice:
        raise InputError(path, "header", f"column {twice[0]} appears more than once")
    clash = [c for c in OUTPUT_COLUMNS if c in header]
    if clash:
        raise InputError(path, "header", f"already has output column {clash[0]}")
    rows = lines[1:]
    if not rows:
        raise InputError(path, "rows", "no points after the header")
    if len(rows) > MAX_POINTS:
        raise InputError(path, "rows", f"has more than {MAX_POINTS:,} points, the most read")
    values = np.empty((len(rows), 4))
    for i, row in enumerate(rows, start=2):
        if len(row) != len(header):
            raise InputError(path, f"line {i}", f"has {len(row)} fields, header has {len(header)}")
        for j, name in enumerate(POINTS_HEADER):
            values[i - 2, j] = csv_number(path, f"line {i}.{name}", row[j], _LIMITS[name])
            if name == "depth" and values[i - 2, j] <= 0:
                raise InputError(path, f"line {i}.depth", f"must be > 0 mm (got {row[j]})")
    return header, rows, values


def read_capture_columns(
    path: str | Path, header: list[str], rows: list[list[str]]
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The optional capture-pose columns of a points CSV read by :func:`read_points_csv`.

    ``capture_x,capture_y,capture_z`` (mm, all three or none) give the hand position each
    point's picture was taken from, ``capture_angle`` (deg) the hand angle θc then. Returns
    ``(position (n, 3) or None, angle (n,) or None)``; ``None``: the calibration's capture.
    """
    path = Path(path)
    xyz = CAPTURE_COLUMNS[:3]
    given = [c for c in xyz if c in header]
    if given and len(given) != 3:
        missing = next(c for c in xyz if c not in header)
        raise InputError(path, "header", f"has {given[0]} but not {missing}: give "
                         f"{','.join(xyz)} together (mm)")  # fmt: skip

    def column(name: str, limit: float) -> np.ndarray:
        j = header.index(name)
        return np.array([csv_number(path, f"line {i}.{name}", row[j], limit)
                         for i, row in enumerate(rows, start=2)])  # fmt: skip

    position = np.stack([column(c, MAX_MM) for c in xyz], axis=1) if given else None
    angle = column("capture_angle", MAX_DEG) if "capture_angle" in header else None
    return position, angle


def csv_number(path: Path, where: str, cell: str, limit: float) -> float:
    """A CSV cell as a finite float at most ``limit`` in magnitude; :class:`InputError` if not.

    ASCII only: Python's ``float`` also reads ``"3_38"`` as 338 and full-width digits.
    """
    try:
        x = parse_float(cell)
    except ValueError:
        raise InputError(path, where, f"not a number: {cell!r}") from None
    if not math.isfinite(x):
        raise InputError(path, where, f"must be finite (got {cell})")
    if abs(x) > limit:
        raise InputError(path, where, f"must be at most {limit:g} in magnitude (got {cell})")
    return x


def check_reach(
    path: str | Path, commands_mm: np.ndarray, reach: Reach, result: str | Path
) -> None:
    """Refuse hand commands beyond ``reach`` (:class:`~handeye_jax._trust.Reach`): an
    :class:`InputError` naming the points file ``path`` and the first such point's line."""
    far = reach.excess_mm(commands_mm)
    i = int(np.argmax(far)) if len(far) else 0
    if len(far) and far[i] > 0:
        command = ", ".join(f"{c:.1f}" for c in commands_mm[i])
        raise InputError(path, f"line {i + 2}", f"its hand command ({command}) mm lies "
                         f"{far[i]:.0f} mm outside the rig's reach ({reach.describe()}): check "
                         f"the point's values, or the result {str(result)!r}")  # fmt: skip


def points_csv_text(header: list[str], rows: list[list[str]], hand_xy_mm: np.ndarray) -> str:
    """The input CSV with ``hand_x,hand_y`` (mm) appended to every row, and ``hand_z`` when
    the commands carry a height (three columns)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    k = np.shape(hand_xy_mm)[1]
    writer.writerow([*header, *OUTPUT_COLUMNS[:k]])
    for row, cmd in zip(rows, hand_xy_mm, strict=True):
        writer.writerow([*row, *(f"{c:.6f}" for c in cmd)])
    return out.getvalue()
