"""Calibration datasets and their file format, ``handeye-jax.dataset/1`` (TOML; mm / deg / px).

A dataset holds what one calibration run measured (the paper's Tables 2 and 3) and the
conventions needed to read it. Lengths are in millimetres, angles in degrees, image and tablet
coordinates in pixels. Every key below is required except ``[search]``; unknown keys are
errors, so a typo never goes unnoticed::

    format = "handeye-jax.dataset/1"
    name = "paper2023"              # non-empty string

    [camera]                        # pinhole intrinsics, px
    fx = 617.7                      # > 0
    fy = 617.7                      # > 0
    cx = 316.5
    cy = 242.3

    [capture]                       # mm, base frame
    hand_position = [320.0, -70.0, 290.0]   # hand position when the picture was taken

    [tablet]                        # eq. (9): one tablet px is 25.4 / ppi * scale mm
    ppi = 267.0                     # > 0
    scale = 2.0                     # > 0

    [hand_angle]                    # phi = zero + sign * hand_angle, deg
    zero = 90.0
    sign = -1                       # exactly 1 or -1

    [search]                        # optional: name = [lo, hi] overrides a model's default
    xt = [100.0, 250.0]             # search range (in the parameter's unit); lo < hi

    [[landmarks]]                   # one table per landmark, at least one
    tablet_px = [400.0, 150.0]      # where it is drawn on the tablet, px; no two alike
    image_px = [119.0, 105.0]       # where the camera sees it, px
    depth = 168.2                   # depth z_c at image_px, mm, > 0
    hand_xy = [289.0, 1.0]          # hand (x, y) when the pen touched it, mm
    hand_angle = 0.0                # hand angle at that touch, deg
    touch_error_px = [-3.0, 1.0]    # touched minus drawn position, tablet px

Numbers may be written as integers or floats (booleans are not numbers); NaN and infinities
are rejected. Values no rig has are refused too: an ``image_px`` more than 80 deg off the
camera's optical axis, a tablet px outside 0.01 to 3 mm, more than 10,000 landmarks, a file
over 4 MiB. :func:`load_dataset` raises :class:`~handeye_jax.errors.InputError` naming the
file and the field (``landmarks[3].depth``, ``camera.fx``, ``search.xt``…) for any violation.
:func:`save_dataset` writes atomically and only what :func:`load_dataset` accepts;
:func:`update_dataset` changes an existing file's values in place, keeping its comments, key
order and layout, and keeps the previous file as ``DATASET.bak``.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np
import tomli_w
import tomlkit
import tomlkit.exceptions
import tomlkit.items

from . import geometry as geo
from ._atomic import StagedFiles, write_output
from ._io import MAX_DATASET_BYTES, parse_toml, read_text
from ._validate import (
    MAX_DEG,
    MAX_LANDMARKS,
    MAX_MEMBER_LANDMARKS,
    MAX_MM,
    MAX_PX,
    MAX_RAY_DEG,
    MM_PER_TABLET_PX,
    Reader,
    describe,
    join_key,
)
from ._x64 import in_float64
from .errors import InputError
from .observations import Observations, Rig, centre_landmark

FORMAT = "handeye-jax.dataset/1"

# Each landmark gives four residual scalars (x and y of both terms of the objective).
RESIDUALS_PER_LANDMARK = 4
# Fewer landmarks than this never pins down a pose, however few the parameters.
MIN_LANDMARKS_TO_FIT = 3

_TOP_KEYS = ("format", "name", "camera", "capture", "tablet", "hand_angle", "search", "landmarks")
_OPTIONAL_TOP_KEYS = ("search",)
_CAMERA_KEYS = ("fx", "fy", "cx", "cy")
_CAPTURE_KEYS = ("hand_position",)
_TABLET_KEYS = ("ppi", "scale")
_HAND_ANGLE_KEYS = ("zero", "sign")
_LANDMARK_KEYS = ("tablet_px", "image_px", "depth", "hand_xy", "hand_angle", "touch_error_px")

# Comments put after the table headers that dataset_to_toml writes.
_HEADER = f"# {FORMAT}: lengths in mm, angles in deg, image and tablet coordinates in px.\n"
_TABLE_COMMENTS = {
    "[camera]": "# pinhole intrinsics, px",
    "[capture]": "# hand position when the picture was taken, mm, base frame",
    "[tablet]": "# one tablet px = 25.4 / ppi * scale mm (eq. 9)",
    "[hand_angle]": "# phi = zero + sign * hand_angle, deg",
    "[search]": "# name = [lo, hi] overrides a model's default search range",
    "[[landmarks]]": "# tablet_px, image_px, touch_error_px: px; depth, hand_xy: mm; "
    "hand_angle: deg",
}


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics: focal lengths and principal point, px."""

    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float


@dataclass(frozen=True, eq=False)
class Dataset:
    """One calibration's measurements and conventions, in mm / deg / px.

    Arrays are float64 NumPy arrays, one row per landmark. Two datasets are equal when every
    field except ``source`` (where the dataset was read from) is equal.

    Attributes:
        name: a label for reports.
        camera: the intrinsics, px.
        capture_position_mm: hand position ``(xh, yh, zh)`` when the picture was taken, mm.
        tablet_ppi, tablet_scale: the tablet's pixel density and display scale (eq. 9).
        hand_angle_zero_deg, hand_angle_sign: ``φ = zero + sign·θh`` (paper notes, item 3).
        search: search-range overrides ``name -> (lo, hi)``, in each parameter's unit.
        tablet_px: where each landmark is drawn on the tablet, px, ``(n, 2)``.
        image_px: where the camera sees it, px, ``(n, 2)``.
        depth_mm: depth ``z_c`` at ``image_px``, mm, ``(n,)``.
        hand_xy_mm: hand ``(x_r, y_r)`` when the pen touched it, mm, ``(n, 2)``.
        hand_angle_deg: hand angle ``θh`` at that touch, deg, ``(n,)``.
        touch_error_px: touched minus drawn position, tablet px, ``(n, 2)``.
        source: the file it was loaded from, if any.
    """

    name: str
    camera: Camera
    capture_position_mm: np.ndarray
    tablet_ppi: float
    tablet_scale: float
    hand_angle_zero_deg: float
    hand_angle_sign: int
    search: dict[str, tuple[float, float]]
    tablet_px: np.ndarray
    image_px: np.ndarray
    depth_mm: np.ndarray
    hand_xy_mm: np.ndarray
    hand_angle_deg: np.ndarray
    touch_error_px: np.ndarray
    source: Path | None = field(default=None)

    def __post_init__(self):
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        for name in _ARRAY_FIELDS:
            put(name, np.array(getattr(self, name), dtype=np.float64))
        if self.capture_position_mm.shape != (3,):
            raise ValueError(
                f"capture_position_mm must have shape (3,), got {self.capture_position_mm.shape}"
            )
        n = self.tablet_px.shape[0] if self.tablet_px.ndim == 2 else -1
        for name, tail in _LANDMARK_ARRAYS.items():
            shape = getattr(self, name).shape
            if n < 0 or shape != (n, *tail):
                want = ", ".join(["n", *map(str, tail)])
                raise ValueError(
                    f"{name} must have shape ({want}), one row per landmark; got {shape} "
                    f"(tablet_px: {self.tablet_px.shape})"
                )
        if self.hand_angle_sign in (1, -1) and not isinstance(self.hand_angle_sign, bool):
            put("hand_angle_sign", int(self.hand_angle_sign))
        put("search", {str(k): (float(v[0]), float(v[1])) for k, v in self.search.items()})
        if self.source is not None:
            put("source", Path(self.source))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Dataset):
            return NotImplemented
        for f in dataclasses.fields(self):
            if f.name == "source":
                continue
            a, b = getattr(self, f.name), getattr(other, f.name)
            if f.name in _ARRAY_FIELDS:
                if not np.array_equal(a, b):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None  # mutable arrays inside: not hashable

    @property
    def n_landmarks(self) -> int:
        return int(self.tablet_px.shape[0])

    @property
    def mm_per_tablet_px(self) -> float:
        """Size of one tablet pixel in mm, eq. (9)."""
        return geo.mm_per_tablet_px(self.tablet_ppi, self.tablet_scale)

    @in_float64
    def rig(self) -> Rig:
        """The known quantities as JAX arrays (float64)."""
        c = self.camera
        return Rig(
            c.fx_px, c.fy_px, c.cx_px, c.cy_px, self.capture_position_mm,
            self.hand_angle_zero_deg, self.hand_angle_sign,
        )  # fmt: skip

    @in_float64
    def observations(self) -> Observations:
        """The landmark data as JAX arrays (float64), tablet quantities converted to mm."""
        mm = self.mm_per_tablet_px
        return Observations(
            rig=self.rig(),
            image_px=jnp.asarray(self.image_px, dtype=float),
            depth_mm=jnp.asarray(self.depth_mm, dtype=float),
            tablet_mm=jnp.asarray(self.tablet_px * mm, dtype=float),
            hand_xy_mm=jnp.asarray(self.hand_xy_mm, dtype=float),
            hand_angle_deg=jnp.asarray(self.hand_angle_deg, dtype=float),
            touch_error_mm=jnp.asarray(self.touch_error_px * mm, dtype=float),
            centre_index=centre_landmark(self.tablet_px),
        )

    def replace(self, **changes: Any) -> Dataset:
        """A copy with some fields changed (:func:`dataclasses.replace`)."""
        return dataclasses.replace(self, **changes)


_ARRAY_FIELDS = (
    "capture_position_mm", "tablet_px", "image_px", "depth_mm", "hand_xy_mm",
    "hand_angle_deg", "touch_error_px",
)  # fmt: skip
# Per-landmark arrays and their shape after the landmark axis.
_LANDMARK_ARRAYS: dict[str, tuple[int, ...]] = {
    "tablet_px": (2,), "image_px": (2,), "depth_mm": (), "hand_xy_mm": (2,),
    "hand_angle_deg": (), "touch_error_px": (2,),
}  # fmt: skip


def known_search_names() -> frozenset[str]:
    """Parameter names a ``[search]`` table may override: every model's and the correction's."""
    from .models import AffinePair, model_registry

    names = set(AffinePair.param_names)
    for cls in model_registry().values():
        names.update(cls.param_names)
    return frozenset(names)


# -- reading with validation ----------------------------------------------------------------


def _parse(doc: dict[str, Any], path: Path | None) -> Dataset:
    r = Reader(path)
    if "format" not in doc:
        r.fail("format", f"missing; expected {FORMAT!r}")
    if doc["format"] != FORMAT:
        r.fail("format", f"expected {FORMAT!r} (got {describe(doc['format'])})")
    r.table(doc, "", _TOP_KEYS, _OPTIONAL_TOP_KEYS)

    name = doc["name"]
    if not isinstance(name, str) or not name.strip():
        r.fail("name", f"must be a non-empty string (got {describe(name)})")

    cam = r.table(doc["camera"], "camera", _CAMERA_KEYS)
    camera = Camera(
        fx_px=r.number(cam["fx"], "camera.fx", True, MAX_PX, minimum=1, unit="px"),
        fy_px=r.number(cam["fy"], "camera.fy", True, MAX_PX, minimum=1, unit="px"),
        cx_px=r.number(cam["cx"], "camera.cx", limit=MAX_PX),
        cy_px=r.number(cam["cy"], "camera.cy", limit=MAX_PX),
    )
    capture = r.table(doc["capture"], "capture", _CAPTURE_KEYS)
    capture_position = r.vector(capture["hand_position"], "capture.hand_position", 3, MAX_MM)
    tablet = r.table(doc["tablet"], "tablet", _TABLET_KEYS)
    ppi = r.number(tablet["ppi"], "tablet.ppi", True, 1e5, minimum=1)
    scale = r.number(tablet["scale"], "tablet.scale", True, 100, minimum=0.01)
    check_tablet_px(ppi, scale, path, "tablet")
    angle = r.table(doc["hand_angle"], "hand_angle", _HAND_ANGLE_KEYS)
    zero = r.number(angle["zero"], "hand_angle.zero", limit=MAX_DEG)
    sign = r.number(angle["sign"], "hand_angle.sign")
    if sign not in (1.0, -1.0):
        r.fail("hand_angle.sign", f"must be 1 or -1 (got {angle['sign']})")

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

    marks = doc["landmarks"]
    if not isinstance(marks, list) or not all(isinstance(m, dict) for m in marks):
        r.fail("landmarks", f"must be an array of tables, [[landmarks]] (got {describe(marks)})")
    if not marks:
        r.fail("landmarks", "needs at least 1 landmark (got 0)")
    if len(marks) > MAX_LANDMARKS:
        r.fail("landmarks", f"has {len(marks):,} landmarks; at most {MAX_LANDMARKS:,} can be "
               "calibrated")  # fmt: skip
    rows: dict[str, list] = {k: [] for k in _LANDMARK_KEYS}
    for i, mark in enumerate(marks):
        where = f"landmarks[{i}]"
        r.table(mark, where, _LANDMARK_KEYS)
        rows["tablet_px"].append(r.vector(mark["tablet_px"], f"{where}.tablet_px", 2, MAX_PX))
        rows["image_px"].append(r.vector(mark["image_px"], f"{where}.image_px", 2, MAX_PX))
        _check_ray(r, rows["image_px"][-1], camera, f"{where}.image_px")
        rows["depth"].append(r.number(mark["depth"], f"{where}.depth", positive=True, limit=MAX_MM))
        rows["hand_xy"].append(r.vector(mark["hand_xy"], f"{where}.hand_xy", 2, MAX_MM))
        rows["hand_angle"].append(
            r.number(mark["hand_angle"], f"{where}.hand_angle", limit=MAX_DEG)
        )
        rows["touch_error_px"].append(
            r.vector(mark["touch_error_px"], f"{where}.touch_error_px", 2, MAX_PX)
        )
    check_distinct(rows["tablet_px"], path)

    return Dataset(
        name=name,
        camera=camera,
        capture_position_mm=np.array(capture_position),
        tablet_ppi=ppi,
        tablet_scale=scale,
        hand_angle_zero_deg=zero,
        hand_angle_sign=int(sign),
        search=search,
        tablet_px=np.array(rows["tablet_px"]),
        image_px=np.array(rows["image_px"]),
        depth_mm=np.array(rows["depth"]),
        hand_xy_mm=np.array(rows["hand_xy"]),
        hand_angle_deg=np.array(rows["hand_angle"]),
        touch_error_px=np.array(rows["touch_error_px"]),
        source=path,
    )


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


def check_distinct(tablet_px: Any, path: str | Path | None) -> None:
    """Two landmarks drawn at the same place are one landmark measured twice: reject."""
    first: dict[tuple[float, float], int] = {}
    for j, xy in enumerate(np.asarray(tablet_px, dtype=np.float64).reshape(-1, 2)):
        key = (float(xy[0]), float(xy[1]))
        if key in first:
            raise InputError(
                path, f"landmarks[{j}].tablet_px",
                f"duplicates landmarks[{first[key]}] (both at [{key[0]}, {key[1]}])",
            )  # fmt: skip
        first[key] = j


def load_dataset(path: str | Path) -> Dataset:
    """Read and validate a ``handeye-jax.dataset/1`` file; raises :class:`InputError`.

    The file must be a regular file of at most 4 MiB
    (:data:`~handeye_jax._io.MAX_DATASET_BYTES`) with at most 10,000 landmarks.
    """
    path = Path(path)
    return _parse_text(_read(path)[1], path)


def _read(path: Path) -> tuple[bytes, str]:
    """The file's bytes and its text (UTF-8, a BOM allowed); :class:`InputError` if unreadable."""
    return read_text(path, MAX_DATASET_BYTES)


def _parse_text(text: str, path: Path, context: str = "") -> Dataset:
    """Validate a dataset's TOML text; ``context`` is added to a TOML syntax error."""
    return _parse(parse_toml(text, path, context), path)


def check_min_landmarks(ds: Dataset, n_params: int, path: str | Path | None = None) -> None:
    """Raise :class:`InputError` unless ``ds`` has enough distinct landmarks to fit ``n_params``.

    Each landmark gives four residual scalars, so ``n_params`` needs ``ceil(n_params / 4)``
    landmarks, and never fewer than three. ``path`` defaults to ``ds.source``.
    """
    path = ds.source if path is None else path
    need = max(MIN_LANDMARKS_TO_FIT, math.ceil(n_params / RESIDUALS_PER_LANDMARK))
    if ds.n_landmarks < need:
        raise InputError(
            path, "landmarks",
            f"needs at least {need} landmarks to fit {n_params} parameters (got {ds.n_landmarks})",
        )  # fmt: skip
    check_distinct(ds.tablet_px, path)


def check_population(ds: Dataset, population: int, path: str | Path | None = None) -> None:
    """Raise :class:`InputError` if DE with ``population`` members on ``ds`` would need more
    memory than a machine has: population x landmarks at most 10^8 (about 5 GB)."""
    path = ds.source if path is None else path
    if population * ds.n_landmarks > MAX_MEMBER_LANDMARKS:
        most = MAX_MEMBER_LANDMARKS // ds.n_landmarks
        raise InputError(
            path, "landmarks",
            f"{ds.n_landmarks:,} landmarks with a DE population of {population:,} need about "
            f"{population * ds.n_landmarks * 48 / 1e9:.0f} GB; use a population of at most "
            f"{most:,} (population x landmarks <= {MAX_MEMBER_LANDMARKS:,})",
        )  # fmt: skip


# -- writing ----------------------------------------------------------------------------------


def _floats(a: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(a).reshape(-1)]


def _to_document(ds: Dataset) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "format": FORMAT,
        "name": ds.name,
        "camera": {
            "fx": float(ds.camera.fx_px), "fy": float(ds.camera.fy_px),
            "cx": float(ds.camera.cx_px), "cy": float(ds.camera.cy_px),
        },
        "capture": {"hand_position": _floats(ds.capture_position_mm)},
        "tablet": {"ppi": float(ds.tablet_ppi), "scale": float(ds.tablet_scale)},
        "hand_angle": {"zero": float(ds.hand_angle_zero_deg), "sign": int(ds.hand_angle_sign)},
    }  # fmt: skip
    if ds.search:
        doc["search"] = {k: [float(lo), float(hi)] for k, (lo, hi) in ds.search.items()}
    doc["landmarks"] = [
        {
            "tablet_px": _floats(ds.tablet_px[i]),
            "image_px": _floats(ds.image_px[i]),
            "depth": float(ds.depth_mm[i]),
            "hand_xy": _floats(ds.hand_xy_mm[i]),
            "hand_angle": float(ds.hand_angle_deg[i]),
            "touch_error_px": _floats(ds.touch_error_px[i]),
        }
        for i in range(ds.n_landmarks)
    ]
    return doc


def _one_line_arrays(text: str) -> str:
    """Join tomli_w's one-item-per-line number arrays into ``key = [a, b]`` lines."""
    out: list[str] = []
    lines = iter(text.split("\n"))  # not splitlines(): strings may hold U+0085, U+2028...
    for line in lines:
        if line.endswith(" = ["):
            items = []
            for item in lines:
                if item == "]":
                    break
                items.append(item.strip().rstrip(","))
            line = f"{line[:-1]}[{', '.join(items)}]"
        out.append(line)
    return "\n".join(out)


def _commented(text: str) -> str:
    """Put a unit comment after the first header of each table."""
    out, done = [], set()
    for line in text.split("\n"):
        if line in _TABLE_COMMENTS and line not in done:
            done.add(line)
            line = f"{line}  {_TABLE_COMMENTS[line]}"
        out.append(line)
    return _HEADER + "\n".join(out)


def dataset_to_toml(ds: Dataset) -> str:
    """The dataset as ``handeye-jax.dataset/1`` text; :func:`load_dataset` reads it back equal."""
    doc = _to_document(ds)
    raw = tomli_w.dumps(doc)
    text = _commented(_one_line_arrays(raw))
    if tomllib.loads(text) != tomllib.loads(raw):  # the reflow must not change a value
        text = raw
    return text


def backup_path(path: str | Path) -> Path:
    """Where :func:`update_dataset` keeps the previous version of a dataset: ``DATASET.bak``."""
    path = Path(path)
    return path.with_name(path.name + ".bak")


def save_dataset(ds: Dataset, path: str | Path) -> None:
    """Write ``ds`` to ``path`` atomically, in the canonical layout: complete or untouched.

    The text is validated as :func:`load_dataset` would before anything is written, so a
    saved file always loads; raises :class:`InputError` for an invalid dataset or an
    unwritable path. To change a user's existing file (keeping its comments and a backup),
    use :func:`update_dataset`.
    """
    path = Path(path)
    text = dataset_to_toml(ds)
    _parse(tomllib.loads(text), path)
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
        for value in new[len(old) :]:
            old.append(value)
    elif not _same(old, new):
        container[key] = new  # tomlkit keeps the old value's indent and trailing comment


def _edited_text(text: str, ds: Dataset) -> str:
    """``text`` (a dataset's TOML) with its values changed to ``ds``'s, layout and comments kept."""
    doc = tomlkit.parse(text)
    new = _to_document(ds)
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
) -> bool:
    """Change the values of the dataset file at ``path`` to ``new``'s, keeping the file's text.

    Only the values that differ are rewritten (with tomlkit), so the user's comments, key order
    and layout survive. ``new`` may be a function of the dataset on disk (read once, so an edit
    made since the caller loaded it is not undone). The current file must be a valid dataset;
    the edited text is validated as :func:`load_dataset` would and must read back equal to
    ``new`` before anything is written; then the previous bytes go to ``backup`` (by default
    :func:`backup_path`; with ``keep_backup``) and the file is replaced, both or neither, so a
    failure at any point leaves the file and its backup byte-identical. Raises
    :class:`InputError` naming the file and field.

    Returns ``True`` if the file was written, ``False`` if it already held these values (then
    nothing, not even the backup, is written).
    """
    path = Path(path)
    raw, text = _read(path)
    current = _parse_text(text, path)
    ds = new(current) if callable(new) else new
    if ds == current:
        return False
    try:
        edited = _edited_text(text, ds)
    except (tomlkit.exceptions.TOMLKitError, KeyError, TypeError, ValueError) as e:
        why = f"cannot edit the file in place ({e}); nothing written"
        raise InputError(path, "", why) from None
    check = _parse_text(edited, path, " after editing in place; nothing written")
    if check != ds:
        raise InputError(path, "", "editing in place does not read back equal; nothing written")
    data = (_BOM if raw.startswith(_BOM) else b"") + edited.encode("utf-8")
    # The backup and the new file land together: a failed write keeps the old backup too.
    files = {Path(backup) if backup else backup_path(path): raw} if keep_backup else {}
    StagedFiles({**files, path: data}).commit()
    return True
