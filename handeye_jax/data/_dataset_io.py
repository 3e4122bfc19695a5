"""Dataset files: ``handeye-jax.dataset/1`` and ``/2`` (TOML; mm, deg, px).

Version 2 (several captures, touches referencing their landmark, an optional hand height)::

    format = "handeye-jax.dataset/2"
    name = "myrig"

    [camera]                        # pinhole intrinsics, px
    fx = 617.7
    fy = 617.7
    cx = 316.5
    cy = 242.3

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

import datetime as dt
import difflib
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w
import tomlkit
import tomlkit.exceptions
import tomlkit.items

from .. import geometry as geo
from .._core import (
    MAX_DATASET_BYTES,
    MAX_DEG,
    MAX_LANDMARKS,
    MAX_MM,
    MAX_PX,
    MAX_RAY_DEG,
    MM_PER_TABLET_PX,
    InputError,
    Reader,
    StagedFiles,
    describe,
    join_key,
    parse_toml,
    read_bytes,
    read_text,
    write_output,
)
from ._dataset import Camera, Capture, Dataset, check_distinct

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
CAMERA = (
    Field("fx", 0, "px", MAX_PX, positive=True, minimum=1),
    Field("fy", 0, "px", MAX_PX, positive=True, minimum=1),
    Field("cx", 0, "px", MAX_PX),
    Field("cy", 0, "px", MAX_PX),
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


# -- reading -----------------------------------------------------------------------------------


def known_search_names() -> frozenset[str]:
    """Parameter names a ``[search]`` table may override: every model's and the correction's."""
    from ..models import AffinePair, model_registry

    names = set(AffinePair.param_names)
    for cls in model_registry().values():
        names.update(cls.param_names)
    return frozenset(names)


def check_tablet_px(ppi: float, scale: float, path: str | Path | None, field: str) -> float:
    """One tablet px in mm (eq. 9); :class:`InputError` naming ``field`` unless a screen's.

    A screen's pixel is :data:`~handeye_jax._validate.MM_PER_TABLET_PX` (0.01 to 3 mm); ppi
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
    """Refuse an image point more than MAX_RAY_DEG off the optical axis: not in a picture."""
    x = (uv[0] - camera.cx_px) / camera.fx_px
    y = (uv[1] - camera.cy_px) / camera.fy_px
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
    camera = Camera(cam["fx"], cam["fy"], cam["cx"], cam["cy"])
    tablet = _read_table(r, doc["tablet"], "tablet", TABLET)
    try:
        check_tablet_px(tablet["ppi"], tablet["scale"], path, "tablet")
    except InputError as e:  # through the reader, which may name an enclosing section
        r.fail(e.field, e.message)
    angle = _read_table(r, doc["hand_angle"], "hand_angle", HAND_ANGLE)
    if angle["sign"] not in (1.0, -1.0):
        r.fail("hand_angle.sign", f"must be 1 or -1 (got {doc['hand_angle']['sign']})")
    search: dict[str, tuple[float, float]] = {}
    if "search" in doc:
        table = doc["search"]
        if not isinstance(table, dict):
            r.fail("search", f"must be a table (got {describe(table)})")
        known = known_search_names()
        for key, value in table.items():
            where = join_key("search", key)
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
                search=search, source=path)  # fmt: skip


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
    camera = common["camera"]
    marks = _array_of_tables(r, doc, "landmarks", MAX_LANDMARKS)
    tablet = [_read_table(r, m, f"landmarks[{i}]", LANDMARK_V2)["tablet_px"]
              for i, m in enumerate(marks)]  # fmt: skip
    _distinct(r, tablet, path)
    n = len(tablet)
    captures = []
    seen: set[int] = set()
    for c, cap in enumerate(_array_of_tables(r, doc, "captures", MAX_CAPTURES)):
        where = f"captures[{c}]"
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
        seen.update(idx)
        captures.append(Capture(pose["hand_position"], pose["hand_angle"], idx,
                                np.reshape(views["image_px"], (k, 2)), views["depth"]))  # fmt: skip
    touches = _array_of_tables(r, doc, "touches", MAX_LANDMARKS * 10, least=0)
    rows: dict[str, list] = {"landmark": [], **{f.key: [] for f in TOUCH_V2}}
    for i, t in enumerate(touches):
        where = f"touches[{i}]"
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
        rows["landmark"].append(m)
        for f in TOUCH_V2:
            rows[f.key].append(row.get(f.key, math.nan))
    t = len(touches)
    return Dataset(
        **common, tablet_px=tablet, captures=captures, touch_landmark=rows["landmark"],
        hand_xy_mm=np.reshape(rows["hand_xy"], (t, 2)), hand_z_mm=rows["hand_z"],
        hand_angle_deg=rows["hand_angle"],
        touch_error_px=np.reshape(rows["touch_error_px"], (t, 2)), version=2,
    )  # fmt: skip


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
    (:data:`~handeye_jax._io.MAX_DATASET_BYTES`) with at most 10,000 landmarks.
    """
    path = Path(path)
    return _parse_text(read_text(path, MAX_DATASET_BYTES)[1], path)


def _parse_text(text: str, path: Path, context: str = "") -> Dataset:
    """Validate a dataset's TOML text; ``context`` is added to a TOML syntax error."""
    return dataset_from_document(parse_toml(text, path, context), path)


# -- writing -----------------------------------------------------------------------------------


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
                                        "cx": ds.camera.cx_px, "cy": ds.camera.cy_px}),
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


# -- updating a file in place ------------------------------------------------------------------

_BOM = b"\xef\xbb\xbf"
_TABLES = (tomlkit.items.Table, tomlkit.items.InlineTable, tomlkit.TOMLDocument)
_ARRAYS = (tomlkit.items.Array, tomlkit.items.AoT)


def _plain(item: Any) -> Any:
    """A tomlkit item as plain Python values (what tomllib would give)."""
    return item.unwrap() if hasattr(item, "unwrap") else item


def _same(old: Any, new: Any) -> bool:
    """Equal values, numbers compared by value (``168`` is ``168.0``), booleans apart."""
    old = _plain(old)
    if isinstance(new, list):
        return (isinstance(old, list) and len(old) == len(new)
                and all(_same(a, b) for a, b in zip(old, new, strict=True)))  # fmt: skip
    if isinstance(new, dict):
        return (
            isinstance(old, dict)
            and old.keys() == new.keys()
            and all(_same(old[k], new[k]) for k in new)
        )
    if isinstance(old, bool) or isinstance(new, bool):
        return type(old) is type(new) and old == new
    return old == new and type(old) in (int, float, str) and type(new) in (int, float, str)


def _sync_table(node: Any, new: dict[str, Any]) -> None:
    """Make the tomlkit table ``node`` hold ``new``, changing only the values that differ."""
    for key in [k for k in node if k not in new]:
        del node[key]
    for key, value in new.items():
        if key not in node:
            node[key] = value
        else:
            _sync_entry(node, key, value)


def _multiline(value: Any) -> Any:
    """An array of arrays (a capture's ``image_px``) as a tomlkit array of one item a line."""
    if isinstance(value, list) and value and all(isinstance(v, list) for v in value):
        array = tomlkit.array()
        array.extend(value)
        array.multiline(True)
        return array
    return value


def _sync_entry(container: Any, key: Any, new: Any) -> None:
    """Set ``container[key]`` to ``new`` in place: unchanged values keep their text."""
    old = container[key]
    if isinstance(new, dict) and isinstance(old, _TABLES):
        _sync_table(old, new)
    elif isinstance(new, list) and isinstance(old, _ARRAYS):
        for i in range(min(len(old), len(new))):
            _sync_entry(old, i, new[i])
        while len(old) > len(new):
            del old[len(old) - 1]
        grown = len(new) > len(old)
        for value in new[len(old) :]:
            if isinstance(old, tomlkit.items.AoT) and isinstance(value, dict):
                table = tomlkit.table()
                for key, v in value.items():
                    table.add(key, _multiline(v))
                table.add(tomlkit.nl())  # a blank line before the next table, as written anew
                value = table
            old.append(value)
        if grown and isinstance(old, tomlkit.items.Array) and any(isinstance(v, list) for v in new):
            old.multiline(True)  # a capture's new image_px: one [u, v] a line, as written anew
    elif not _same(old, new):
        container[key] = new  # tomlkit keeps the old value's indent and trailing comment


def _edited_text(text: str, ds: Dataset, version: int) -> str:
    """``text`` (a dataset's TOML) with its values changed to ``ds``'s, layout and comments kept."""
    doc = tomlkit.parse(text)
    new = dataset_to_document(ds, version)
    if "search" not in new and "search" in doc:
        new["search"] = {}  # keep the (now empty) table and its comments
    _sync_table(doc, new)
    return tomlkit.dumps(doc)


def update_dataset(
    path: str | Path,
    new: Dataset | Callable[[Dataset], Dataset],
    *,
    keep_backup: bool = True,
    backup: str | Path | None = None,
) -> Path | None:
    """Change the values of the dataset file at ``path`` to ``new``'s, keeping the file's text.

    Only the values that differ are rewritten (with tomlkit), so the user's comments, key order
    and layout survive; a version-1 file stays version 1 while ``new`` fits it. ``new`` may be
    a function of the dataset on disk (read once, so an edit made since the caller loaded it is
    not undone). The current file must be a valid dataset; the edited text is validated as
    :func:`load_dataset` would and must read back equal to ``new`` before anything is written;
    then the previous bytes go to ``backup`` (by default a new :func:`backup_path`, so every
    version is kept; with ``keep_backup``) and the file is replaced, both or neither, so a
    failure at any point leaves the file and its backups byte-identical. Raises
    :class:`InputError` naming the file and field.

    Returns the backup written, or ``None`` if there was none (``keep_backup=False``, or the
    file already held these values: then nothing is written).
    """
    path = Path(path)
    raw, text = read_text(path, MAX_DATASET_BYTES)
    current = _parse_text(text, path)
    ds = new(current) if callable(new) else new
    if ds == current:
        return None
    try:
        edited = _edited_text(text, ds, current.version)
    except (tomlkit.exceptions.TOMLKitError, KeyError, TypeError, ValueError) as e:
        why = f"cannot edit the file in place ({e}); nothing written"
        raise InputError(path, "", why) from None
    check = _parse_text(edited, path, " after editing in place; nothing written")
    if check != ds:
        raise InputError(path, "", "editing in place does not read back equal; nothing written")
    data = (_BOM if raw.startswith(_BOM) else b"") + edited.encode("utf-8")
    # The backup and the new file land together: a failed write keeps the old backups too.
    target = (Path(backup) if backup else backup_path(path)) if keep_backup else None
    files = {target: raw} if target is not None else {}
    StagedFiles({**files, path: data}).commit()
    return target


def convert_path(path: str | Path) -> Path:
    """Where :func:`convert_to_v2` writes by default: ``NAME.v2.toml`` beside ``NAME.toml``."""
    path = Path(path)
    stem = path.name.removesuffix(".toml") if path.name.endswith(".toml") else path.name
    return path.with_name(f"{stem}.v2.toml")


def convert_to_v2(
    path: str | Path,
    out: str | Path | None = None,
    *,
    overwrite: bool = False,
    backup: str | Path | None = None,
) -> Dataset:
    """Read a dataset (either version) and write it to ``out`` as version 2; returns it.

    Args:
        path: the dataset to read (``handeye-jax.dataset/1`` or ``/2``).
        out: where to write (default :func:`convert_path`, ``NAME.v2.toml`` beside it); may be
            ``path`` itself, with ``overwrite``.
        overwrite: replace an existing ``out``; its previous bytes are kept at ``backup``
            (default a new ``OUT.<UTC time>.bak``, :func:`backup_path`), written together with
            the new file (both or neither). Without it an existing ``out`` is refused.
        backup: where the replaced file goes.

    The new file is in the canonical layout (the old file's comments are not carried over;
    the old file stays, at ``path`` or as the backup). The written text is validated as
    :func:`load_dataset` reads it and reads back equal to the dataset before anything is
    written. Raises :class:`InputError` naming the file and field.
    """
    path = Path(path)
    out = convert_path(path) if out is None else Path(out)
    ds = _parse_text(read_text(path, MAX_DATASET_BYTES)[1], path)
    text = dataset_to_toml(ds, version=2)
    if dataset_from_document(tomllib.loads(text), out) != ds:  # never a lossy conversion
        raise InputError(path, "", "the version-2 text does not read back equal; nothing written")
    files: dict[Path, bytes] = {}
    if out.exists():
        if not overwrite:
            raise InputError(out, "", "exists; not overwritten (overwrite=True replaces it and "
                             "keeps it as a backup)")  # fmt: skip
        target = Path(backup) if backup is not None else backup_path(out)
        files[target] = read_bytes(out, MAX_DATASET_BYTES, "dataset to replace")
    files[out] = text.encode("utf-8")
    StagedFiles(files).commit()
    return ds
