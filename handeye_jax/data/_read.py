"""Reading a dataset file: both versions checked field by field, every error naming the
file and the field; the tables of :mod:`._tables` describe each field."""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Any

import numpy as np

from .. import geometry as geo
from .._core import (
    MAX_DATASET_BYTES,
    MAX_LANDMARKS,
    MAX_RAY_DEG,
    MM_PER_TABLET_PX,
    SEARCH_PRESETS,
    InputError,
    Reader,
    describe,
    join_key,
    parse_toml,
    read_text,
)
from ._dataset import Camera, Capture, Dataset, check_distinct
from ._tables import (
    _TOP_V1,
    _TOP_V2,
    CAMERA,
    CAPTURE_V1,
    CAPTURE_V2,
    CAPTURE_VIEWS,
    FORMAT_V1,
    FORMAT_V2,
    FORMATS,
    HAND_ANGLE,
    LANDMARK_V1,
    LANDMARK_V2,
    MAX_CAPTURES,
    TABLET,
    TOUCH_V2,
    _keys,
    _read_table,
)


def known_search_names() -> frozenset[str]:
    """Parameter names a ``[search]`` table may override: every model's and the correction's."""
    from ..models import AffinePair, model_registry

    names = set(AffinePair.param_names)
    for cls in model_registry().values():
        names.update(cls.param_names)
    return frozenset(names)


def check_tablet_px(ppi: float, scale: float, path: str | Path | None, field: str) -> float:
    """One tablet px in mm (eq. 9); :class:`InputError` naming ``field`` unless a screen's.

    A screen's pixel is :data:`~handeye_jax._core.MM_PER_TABLET_PX` (0.01 to 3 mm); ppi
    and scale that make it larger or smaller are a typo (``ppi = 1``, ``scale = 100``: 2.5 m).
    """
    mm = geo.mm_per_tablet_px(ppi, scale)
    lo, hi = MM_PER_TABLET_PX
    if not lo <= mm <= hi:
        raise InputError(
            path, field,
            f"one tablet px is 25.4 / ppi * scale = {mm:.4g} mm (ppi {ppi:g}, scale {scale:g}); "
            f"a screen's pixel is {lo:g} to {hi:g} mm: check ppi and scale",
        )  # fmt: skip
    return mm


def _check_ray(r: Reader, uv: list[float], camera: Camera, where: str) -> None:
    """Refuse an image point more than MAX_RAY_DEG off the optical axis (not in a picture),
    or one the camera's distortion cannot undistort."""
    ideal = camera.undistort(uv)[0]
    if not np.isfinite(ideal).all():
        r.fail(where, f"cannot be undistorted with [camera]'s distortion (the model does not "
               f"invert there; got [{uv[0]:g}, {uv[1]:g}]): check camera.distortion")  # fmt: skip
    x = (ideal[0] - camera.cx_px) / camera.fx_px
    y = (ideal[1] - camera.cy_px) / camera.fy_px
    angle = math.degrees(math.atan(math.hypot(x, y)))
    if angle > MAX_RAY_DEG:
        r.fail(where, f"is {angle:.1f} deg off the camera's optical axis (at most "
               f"{MAX_RAY_DEG:g} deg with [camera]'s fx, fy, cx, cy): no point of a picture; "
               f"check image_px and [camera] (got [{uv[0]:g}, {uv[1]:g}])")  # fmt: skip


def _array_of_tables(r: Reader, doc: dict, key: str, most: int, least: int = 1) -> list[dict]:
    rows = doc[key]
    if not isinstance(rows, list) or not all(isinstance(m, dict) for m in rows):
        r.fail(key, f"must be an array of tables, [[{key}]] (got {describe(rows)})")
    if len(rows) < least:
        noun = key[:-1] if least == 1 else key
        r.fail(key, f"needs at least {least} {noun} (got {len(rows)})")
    if len(rows) > most:
        r.fail(key, f"has {len(rows):,} {key}; at most {most:,} can be calibrated")
    return rows


def _common(r: Reader, doc: dict, path: Path | None) -> dict[str, Any]:
    """What both versions share: name, camera, tablet, hand-angle convention, search."""
    name = doc["name"]
    if not isinstance(name, str) or not name.strip():
        r.fail("name", f"must be a non-empty string (got {describe(name)})")
    cam = _read_table(r, doc["camera"], "camera", CAMERA)
    camera = Camera(cam["fx"], cam["fy"], cam["cx"], cam["cy"], cam.get("distortion"))
    tablet = _read_table(r, doc["tablet"], "tablet", TABLET)
    try:
        check_tablet_px(tablet["ppi"], tablet["scale"], path, "tablet")
    except InputError as e:  # through the reader, which may name an enclosing section
        r.fail(e.field, e.message)
    angle = _read_table(r, doc["hand_angle"], "hand_angle", HAND_ANGLE)
    if angle["sign"] not in (1.0, -1.0):
        r.fail("hand_angle.sign", f"must be 1 or -1 (got {doc['hand_angle']['sign']})")
    search: dict[str, tuple[float, float]] = {}
    preset = None
    if "search" in doc:
        table = doc["search"]
        if not isinstance(table, dict):
            r.fail("search", f"must be a table (got {describe(table)})")
        known = known_search_names()
        for key, value in table.items():
            where = join_key("search", key)
            if key == "preset":
                if value not in SEARCH_PRESETS:
                    r.fail(where, f"must be one of {', '.join(map(repr, SEARCH_PRESETS))} (got "
                           f"{describe(value)})")  # fmt: skip
                preset = value
                continue
            if key not in known:
                hint = difflib.get_close_matches(key, sorted(known), n=1)
                more = f"did you mean {hint[0]!r}?" if hint else "no model has this parameter"
                r.fail(where, f"unknown parameter name; {more}")
            lo, hi = r.vector(value, where, 2, 1e6)
            if not lo < hi:
                r.fail(where, f"must be [lo, hi] with lo < hi (got [{lo}, {hi}])")
            search[key] = (lo, hi)
    return dict(name=name, camera=camera, tablet_ppi=tablet["ppi"], tablet_scale=tablet["scale"],
                hand_angle_zero_deg=angle["zero"], hand_angle_sign=int(angle["sign"]),
                search=search, search_preset=preset, source=path)  # fmt: skip


def _distinct(r: Reader, tablet_px: Any, path: Path | None) -> None:
    try:
        check_distinct(tablet_px, path)
    except InputError as e:  # through the reader, which may name an enclosing section
        r.fail(e.field, e.message)


def _parse_v1(r: Reader, doc: dict, path: Path | None) -> Dataset:
    r.table(doc, "", _TOP_V1, ("search",))
    common = _common(r, doc, path)
    camera = common["camera"]
    capture = _read_table(r, doc["capture"], "capture", CAPTURE_V1)
    marks = _array_of_tables(r, doc, "landmarks", MAX_LANDMARKS)
    rows: dict[str, list] = {f.key: [] for f in LANDMARK_V1}
    for i, mark in enumerate(marks):
        where = f"landmarks[{i}]"
        row = _read_table(r, mark, where, LANDMARK_V1)
        _check_ray(r, row["image_px"], camera, f"{where}.image_px")
        for k, v in row.items():
            rows[k].append(v)
    _distinct(r, rows["tablet_px"], path)
    return Dataset(
        **common, tablet_px=rows["tablet_px"], capture_position_mm=capture["hand_position"],
        image_px=rows["image_px"], depth_mm=rows["depth"], hand_xy_mm=rows["hand_xy"],
        hand_angle_deg=rows["hand_angle"], touch_error_px=rows["touch_error_px"], version=1,
    )  # fmt: skip


def _parse_v2(r: Reader, doc: dict, path: Path | None) -> Dataset:
    r.table(doc, "", _TOP_V2, ("search",))
    common = _common(r, doc, path)
    marks = _array_of_tables(r, doc, "landmarks", MAX_LANDMARKS)
    tablet = [_read_table(r, m, f"landmarks[{i}]", LANDMARK_V2)["tablet_px"]
              for i, m in enumerate(marks)]  # fmt: skip
    _distinct(r, tablet, path)
    n = len(tablet)
    tables = _array_of_tables(r, doc, "captures", MAX_CAPTURES)
    captures = [_capture_v2(r, cap, f"captures[{c}]", n, common["camera"])
                for c, cap in enumerate(tables)]  # fmt: skip
    seen = {int(m) for cap in captures for m in cap.landmarks}
    touches = _array_of_tables(r, doc, "touches", MAX_LANDMARKS * 10, least=0)
    rows: dict[str, list] = {"landmark": [], **{f.key: [] for f in TOUCH_V2}}
    for i, t in enumerate(touches):
        row = _touch_v2(r, t, f"touches[{i}]", n, seen)
        for key, value in row.items():
            rows[key].append(value)
    t = len(touches)
    return Dataset(
        **common, tablet_px=tablet, captures=captures, touch_landmark=rows["landmark"],
        hand_xy_mm=np.reshape(rows["hand_xy"], (t, 2)), hand_z_mm=rows["hand_z"],
        hand_angle_deg=rows["hand_angle"],
        touch_error_px=np.reshape(rows["touch_error_px"], (t, 2)), version=2,
    )  # fmt: skip


def _capture_v2(r: Reader, cap: Any, where: str, n: int, camera: Camera) -> Capture:
    """One ``[[captures]]`` table of a version-2 file, of ``n`` landmarks."""
    pose = _read_table(r, cap, where, CAPTURE_V2, ("landmarks", *_keys(CAPTURE_VIEWS)))
    for key in ("landmarks", *_keys(CAPTURE_VIEWS)):
        if key not in cap:
            r.fail(join_key(where, key), "missing")
    idx = cap["landmarks"]
    if not isinstance(idx, list) or not all(isinstance(m, int) and not isinstance(m, bool)
                                            for m in idx):  # fmt: skip
        r.fail(f"{where}.landmarks", f"must be an array of landmark indices (got "
               f"{describe(idx)})")  # fmt: skip
    for j, m in enumerate(idx):
        if not 0 <= m < n:
            r.fail(f"{where}.landmarks[{j}]", f"must be a landmark index, 0 to {n - 1} "
                   f"(got {m})")  # fmt: skip
        if m in idx[:j]:
            r.fail(f"{where}.landmarks[{j}]", f"landmark {m} is listed twice in one capture")
    k = len(idx)
    views = {}
    for f in CAPTURE_VIEWS:
        rows = cap[f.key]
        if not isinstance(rows, list) or len(rows) != k:
            r.fail(f"{where}.{f.key}", f"must be an array of {k}, one per entry of "
                   f"landmarks (got {describe(rows)})")  # fmt: skip
        views[f.key] = [f.read(r, v, f"{where}.{f.key}[{j}]") for j, v in enumerate(rows)]
    for j, uv in enumerate(views["image_px"]):
        _check_ray(r, uv, camera, f"{where}.image_px[{j}]")
    return Capture(pose["hand_position"], pose["hand_angle"], idx,
                   np.reshape(views["image_px"], (k, 2)), views["depth"])  # fmt: skip


def _touch_v2(r: Reader, t: Any, where: str, n: int, seen: set[int]) -> dict[str, Any]:
    """One ``[[touches]]`` table of a version-2 file: its landmark and fields (NaN where an
    optional one is left out); ``seen``: the landmarks some capture sees."""
    row = _read_table(r, t, where, TOUCH_V2, ("landmark",))
    if "landmark" not in t:
        r.fail(f"{where}.landmark", "missing")
    m = t["landmark"]
    if isinstance(m, bool) or not isinstance(m, int) or not 0 <= m < n:
        r.fail(f"{where}.landmark", f"must be a landmark index, 0 to {n - 1} (got "
               f"{describe(m)})")  # fmt: skip
    if m not in seen:
        r.fail(f"{where}.landmark", f"landmark {m} is in no capture: a touch needs a "
               "picture of what it touched")  # fmt: skip
    return {"landmark": m, **{f.key: row.get(f.key, math.nan) for f in TOUCH_V2}}


def dataset_from_document(doc: Any, path: str | Path | None, where: str = "") -> Dataset:
    """A validated dataset from a parsed document (a TOML file's, or a result's ``data``)."""
    path = None if path is None else Path(path)
    r = Reader(path) if not where else _Nested(path, where)
    if not isinstance(doc, dict):
        r.fail("", f"must be a table (got {describe(doc)})")
    if "format" not in doc:
        r.fail("format", f"missing; expected {FORMAT_V1!r} or {FORMAT_V2!r}")
    version = FORMATS.get(doc["format"]) if isinstance(doc["format"], str) else None
    if version is None:
        r.fail("format", f"expected {FORMAT_V1!r} or {FORMAT_V2!r} (got "
               f"{describe(doc['format'])})")  # fmt: skip
    return (_parse_v1 if version == 1 else _parse_v2)(r, doc, path)


class _Nested(Reader):
    """A reader whose fields sit under ``where`` (a result's ``data`` section)."""

    def __init__(self, path: Path | None, where: str):
        super().__init__(path)
        self.where = where

    def fail(self, where: str, message: str):
        raise InputError(self.path, join_key(self.where, where) if where else self.where, message)


def load_dataset(path: str | Path) -> Dataset:
    """Read and validate a ``handeye-jax.dataset/1`` or ``/2`` file; raises
    :class:`InputError` naming the file and the field.

    The file must be a regular file of at most 4 MiB
    (:data:`~handeye_jax._core.MAX_DATASET_BYTES`) with at most 10,000 landmarks.
    """
    path = Path(path)
    return parse_dataset_text(read_text(path, MAX_DATASET_BYTES)[1], path)


def parse_dataset_text(text: str, path: Path, context: str = "") -> Dataset:
    """Validate a dataset's TOML text; ``context`` is added to a TOML syntax error."""
    return dataset_from_document(parse_toml(text, path, context), path)
