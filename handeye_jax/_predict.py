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
    from .models import AbstractCorrection, AbstractModel

POINTS_HEADER = ("u", "v", "depth", "hand_angle")
OUTPUT_COLUMNS = ("hand_x", "hand_y")
_LIMITS = {"u": MAX_PX, "v": MAX_PX, "depth": MAX_MM, "hand_angle": MAX_DEG}


def hand_command(
    model: AbstractModel,
    rig: Rig,
    image_px: Float[Array, "n 2"],
    depth_mm: Float[Array, " n"],
    hand_angle_deg: Float[Array, " n"],
    correction: AbstractCorrection | None = None,
    centres_mm: Float[Array, "2 2"] | None = None,
) -> Float[Array, "n 2"]:
    """Where to send the hand, ``(x, y)`` in mm in the base frame, so the pen touches each point.

    Args:
        model: a fitted stage-1 model.
        rig: the rig the model was fitted with (intrinsics, capture pose, angle convention).
        image_px: ``(u, v)`` of each target in the captured picture, px.
        depth_mm: depth at each target, mm.
        hand_angle_deg: the hand angle θh the robot will touch with, deg.
        correction: the fitted stage-2 correction; ``None`` gives eq. (8) (stage 1).
        centres_mm: the correction's centres of rotation (rows: A1, A2), fixed at calibration.
    """
    x_bi = model.image_to_base(image_px, depth_mm, rig)[:, :2]
    offset = model.pen_offset(rig.phi_deg(hand_angle_deg))[:, :2]
    if correction is None:
        return x_bi - offset
    return correction.second(correction.first(x_bi, centres_mm[0]) - offset, centres_mm[1])


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


def points_csv_text(header: list[str], rows: list[list[str]], hand_xy_mm: np.ndarray) -> str:
    """The input CSV with ``hand_x,hand_y`` (mm) appended to every row."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow([*header, *OUTPUT_COLUMNS])
    for row, (x, y) in zip(rows, hand_xy_mm, strict=True):
        writer.writerow([*row, f"{x:.6f}", f"{y:.6f}"])
    return out.getvalue()
