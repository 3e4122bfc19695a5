"""The points CSV of ``predict``: ``u,v,depth,hand_angle`` (px, px, mm, deg) in, with
``hand_x,hand_y`` (and ``hand_z``), mm, out; NumPy only (the robot's predictor reads it)."""

from __future__ import annotations

import csv
import io
import itertools
import math
from pathlib import Path

import numpy as np

from .._core import (
    MAX_DEG,
    MAX_MM,
    MAX_POINTS,
    MAX_PX,
    MAX_TEXT_BYTES,
    InputError,
    csv_rows,
    parse_float,
    read_text,
)

POINTS_HEADER = ("u", "v", "depth", "hand_angle")
OUTPUT_COLUMNS = ("hand_x", "hand_y", "hand_z")
#: Optional columns: the hand pose each point's picture was taken from (mm, mm, mm, deg).
CAPTURE_COLUMNS = ("capture_x", "capture_y", "capture_z", "capture_angle")
_LIMITS = {"u": MAX_PX, "v": MAX_PX, "depth": MAX_MM, "hand_angle": MAX_DEG}


def read_points_csv(path: str | Path) -> tuple[list[str], list[list[str]], np.ndarray]:
    """Read a points CSV; returns ``(header, rows, values)`` with ``values`` (n, 4) float64.

    The header must start with ``u,v,depth,hand_angle``; extra columns are kept as they are.
    At most 100,000 points (:data:`~handeye_jax._core.MAX_POINTS`) in at most 16 MiB.
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
