"""Writing a dataset file: the canonical layout of either version, atomically, with the
previous version kept as a backup."""

from __future__ import annotations

import datetime as dt
import tomllib
from pathlib import Path
from typing import Any

import tomli_w

from .._core import (
    write_output,
)
from ._dataset import Dataset
from ._read import dataset_from_document
from ._tables import (
    CAMERA,
    CAPTURE_V1,
    CAPTURE_V2,
    FORMAT_V1,
    FORMAT_V2,
    LANDMARK_V1,
    LANDMARK_V2,
    TABLET,
    TOUCH_V2,
    _write_table,
)


def dataset_to_document(ds: Dataset, version: int | None = None) -> dict[str, Any]:
    """The dataset as a plain document (what its TOML file parses to), in ``version`` (default:
    its own; version 1 only for a simple dataset without hand heights)."""
    version = ds.version if version is None else version
    if version == 1 and not (ds.is_simple() and not ds.has_hand_z):
        version = 2
    doc: dict[str, Any] = {
        "format": FORMAT_V1 if version == 1 else FORMAT_V2,
        "name": ds.name,
        "camera": _write_table(CAMERA, {"fx": ds.camera.fx_px, "fy": ds.camera.fy_px,
                                        "cx": ds.camera.cx_px, "cy": ds.camera.cy_px,
                                        "distortion": ds.camera.distortion}),
    }  # fmt: skip
    tablet = _write_table(TABLET, {"ppi": ds.tablet_ppi, "scale": ds.tablet_scale})
    angle = {"zero": float(ds.hand_angle_zero_deg), "sign": int(ds.hand_angle_sign)}
    search = {k: [float(lo), float(hi)] for k, (lo, hi) in ds.search.items()}
    if version == 1:
        cap = ds.captures[0]
        doc["capture"] = _write_table(CAPTURE_V1, {"hand_position": cap.hand_position_mm})
        doc["tablet"], doc["hand_angle"] = tablet, angle
        if search:
            doc["search"] = search
        doc["landmarks"] = [
            _write_table(
                LANDMARK_V1,
                {
                    "tablet_px": ds.tablet_px[i],
                    "image_px": cap.image_px[i],
                    "depth": cap.depth_mm[i],
                    "hand_xy": ds.hand_xy_mm[i],
                    "hand_angle": ds.hand_angle_deg[i],
                    "touch_error_px": ds.touch_error_px[i],
                },
            )  # fmt: skip
            for i in range(ds.n_landmarks)
        ]
        return doc
    doc["tablet"], doc["hand_angle"] = tablet, angle
    if search:
        doc["search"] = search
    doc["landmarks"] = [_write_table(LANDMARK_V2, {"tablet_px": p}) for p in ds.tablet_px]
    doc["captures"] = [
        {
            **_write_table(
                CAPTURE_V2, {"hand_position": c.hand_position_mm, "hand_angle": c.hand_angle_deg}
            ),
            "landmarks": [int(m) for m in c.landmarks],
            "image_px": [[float(u), float(v)] for u, v in c.image_px],
            "depth": [float(z) for z in c.depth_mm],
        }  # fmt: skip
        for c in ds.captures
    ]
    doc["touches"] = [
        {"landmark": int(ds.touch_landmark[i]), **_write_table(TOUCH_V2, {
            "hand_xy": ds.hand_xy_mm[i], "hand_z": ds.hand_z_mm[i],
            "hand_angle": ds.hand_angle_deg[i], "touch_error_px": ds.touch_error_px[i]})}
        for i in range(ds.n_touches)
    ]  # fmt: skip
    return doc


# Comments put after the table headers that dataset_to_toml writes.
_TABLE_COMMENTS = {
    "[camera]": "# pinhole intrinsics, px",
    "[capture]": "# hand position when the picture was taken, mm, base frame",
    "[tablet]": "# one tablet px = 25.4 / ppi * scale mm (eq. 9)",
    "[hand_angle]": "# phi = zero + sign * hand_angle, deg",
    "[search]": "# name = [lo, hi] overrides a model's default search range",
    "[[landmarks]]": "# tablet_px, image_px, touch_error_px: px; depth, hand_xy: mm; "
    "hand_angle: deg",
    "[[captures]]": "# hand_position, depth: mm; hand_angle: deg; image_px: px",
    "[[touches]]": "# hand_xy, hand_z: mm; hand_angle: deg; touch_error_px: tablet px",
}
_TABLE_COMMENTS_V2 = {"[[landmarks]]": "# tablet_px: where each landmark is drawn, tablet px"}


def _one_line_arrays(text: str) -> str:
    """Join tomli_w's one-item-per-line arrays into ``key = [a, b]`` lines; an array of
    arrays (a capture's ``image_px``) keeps one inner ``[u, v]`` per line."""
    out: list[str] = []
    lines = iter(text.split("\n"))  # not splitlines(): strings may hold U+0085, U+2028...
    for line in lines:
        if line.endswith(" = ["):
            inner = []
            for item in lines:
                if item == "]":
                    break
                inner.append(item.strip())
            if "[" not in inner:
                line = f"{line[:-1]}[{', '.join(i.rstrip(',') for i in inner)}]"
            else:
                rows, row = [], []
                for item in inner:
                    if item == "[":
                        row = []
                    elif item in ("]", "],"):
                        rows.append(f"    [{', '.join(row)}],")
                    else:
                        row.append(item.rstrip(","))
                line = "\n".join([line, *rows, "]"])
        out.append(line)
    return "\n".join(out)


def _commented(text: str, format_: str) -> str:
    """Put a unit comment after the first header of each table."""
    out, done = [], set()
    comments = _TABLE_COMMENTS | (_TABLE_COMMENTS_V2 if format_ == FORMAT_V2 else {})
    for line in text.split("\n"):
        if line in comments and line not in done:
            done.add(line)
            line = f"{line}  {comments[line]}"
        out.append(line)
    header = f"# {format_}: lengths in mm, angles in deg, image and tablet coordinates in px.\n"
    return header + "\n".join(out)


def dataset_to_toml(ds: Dataset, version: int | None = None) -> str:
    """The dataset as TOML text (see :func:`dataset_to_document`); :func:`load_dataset` reads
    it back equal."""
    doc = dataset_to_document(ds, version)
    raw = tomli_w.dumps(doc)
    text = _commented(_one_line_arrays(raw), doc["format"])
    try:  # the reflow must not change a value (nor break nested arrays)
        same = tomllib.loads(text) == tomllib.loads(raw)
    except tomllib.TOMLDecodeError:
        same = False
    return text if same else raw


def backup_path(path: str | Path, now: dt.datetime | None = None) -> Path:
    """A new name for the previous version of a dataset: ``DATASET.<UTC time>.bak``, with
    ``-2``, ``-3``… when that name is taken, so no version is ever overwritten."""
    path = Path(path)
    now = now or dt.datetime.now(dt.UTC)
    stamp = now.strftime("%Y-%m-%dT%H-%M-%S.") + f"{now.microsecond // 1000:03d}Z"
    candidate = path.with_name(f"{path.name}.{stamp}.bak")
    k = 2
    while candidate.exists():
        candidate = path.with_name(f"{path.name}.{stamp}-{k}.bak")
        k += 1
    return candidate


def save_dataset(ds: Dataset, path: str | Path, version: int | None = None) -> None:
    """Write ``ds`` to ``path`` atomically, in the canonical layout: complete or untouched.

    The text is validated as :func:`load_dataset` would before anything is written, so a
    saved file always loads; raises :class:`InputError` for an invalid dataset or an
    unwritable path. To change a user's existing file (keeping its comments and a backup),
    use :func:`update_dataset`.
    """
    path = Path(path)
    text = dataset_to_toml(ds, version)
    dataset_from_document(tomllib.loads(text), path)
    write_output(path, text)
