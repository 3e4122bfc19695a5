"""Result files: ``handeye-jax.result/1`` (JSON), written and read back with every field checked.

The layout (every section but the first eight is optional; older files load)::

    format, model, seed, settings{...}, dataset, timings_s{stage1_de, ..., total}
    rig{camera_px{fx,fy,cx,cy}, capture_hand_position_mm, hand_angle{zero_deg, sign}}
    stage1, stage2: StageResult{F, f1, f2, params{name: value}, residuals_mm[...], de{...},
                                polish{...}, convergence{...}, status{...}, fixed_source{...},
                                prior{...}, prior_F}
    centre_index, centres_mm[[x, y], [x, y]], sign_twin{...}, warnings[]
    frames{...}                 # the fitted frames as numbers, for the NumPy predictor
    content_sha256              # of all the rest: while it matches, the frames need no check
    recalibration{previous, refit[], others}
    deploy{stage, evidence, reason, stage1_mm, stage2_mm, ...}   # the stage to deploy
    heights{...}
    search{preset, stage1{name: {lower, upper, source}}, stage2{...}, estimate{...}, ...}
    diagnostics{...}
    data{...}                   # the dataset fitted, as its own file's document (v1 or v2)
    observations{...}           # older results: the landmark arrays instead of ``data``

The schema is written once: each section's payload class (:class:`StageResult`,
:mod:`._payloads`, :class:`RigRecord`) describes its fields, and :data:`SECTIONS` the
top-level ones; :func:`result_to_document` writes them and :func:`load_result` reads and
checks the whole file with them, plus the rules across sections (landmark counts, the
centre landmark, the parameters' names). The data section is read by the dataset's own
reader (:mod:`handeye_jax.data`): one schema.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .._core import (
    DIGEST_KEY,
    MAX_DEG,
    MAX_LANDMARKS,
    MAX_MM,
    MAX_PX,
    MAX_RESULT_BYTES,
    MM_PER_TABLET_PX,
    SEARCH_PRESETS,
    InputError,
    Reader,
    describe,
    document_digest,
    load_json,
    read,
    spec,
    to_document,
    write_output,
)
from .._jax import in_float64
from ..data import Camera, Dataset, dataset_from_document, dataset_to_document
from ..models import AffinePair, Rig, get_model, model_registry
from ..problem import Heights
from ..robot import TRANSLATIONS, Frames, check_result_document, read_json
from ._payloads import Deployment, Diagnostics, FitWarning, Recalibration, SignTwin
from ._ranges import SOURCES, SearchReport
from ._result import MAX_PARAM, CalibrationResult, StageResult
from ._result_frames import UNDETERMINED
from ._settings import SEED_RANGE, read_settings

FORMAT = "handeye-jax.result/1"
#: Stage-2 parameters that are scale factors (> 0: zero collapses the plane, < 0 mirrors it).
AFFINE_SCALES = ("Sx1", "Sy1", "Sx2", "Sy2")
#: The landmark arrays of an older result's ``observations``: name → shape after the row.
LEGACY_OBSERVATIONS: dict[str, tuple[int, ...]] = {
    "tablet_px": (2,), "image_px": (2,), "depth_mm": (), "hand_xy_mm": (2,),
    "hand_angle_deg": (), "touch_error_px": (2,),
}  # fmt: skip
_LEGACY_LIMITS = {
    "tablet_px": MAX_PX, "image_px": MAX_PX, "depth_mm": MAX_MM, "hand_xy_mm": MAX_MM,
    "hand_angle_deg": MAX_DEG, "touch_error_px": MAX_PX,
}  # fmt: skip


# -- the rig -------------------------------------------------------------------------------


def _focal(r: Reader, x: float, where: str) -> float:
    return r.number(x, where, True, MAX_PX, minimum=1, unit="px")


def _within(limit: float):
    return lambda r, x, where: r.number(x, where, limit=limit)


def _each_within(limit: float):
    return lambda r, x, where: tuple(r.number(v, f"{where}[{i}]", limit=limit)
                                     for i, v in enumerate(x))  # fmt: skip


def _sign(r: Reader, x: int, where: str) -> int:
    if x not in (1, -1):
        r.fail(where, f"must be 1 or -1 (got {x})")
    return x


@dataclass(frozen=True)
class CameraPx:
    """Pinhole intrinsics, px."""

    strict: ClassVar[bool] = True

    fx: float = spec(check=_focal)
    fy: float = spec(check=_focal)
    cx: float = spec(check=_within(MAX_PX))
    cy: float = spec(check=_within(MAX_PX))


@dataclass(frozen=True)
class HandAngle:
    """The hand-angle convention ``φ = zero + sign·θh``."""

    strict: ClassVar[bool] = True

    zero_deg: float = spec(check=_within(MAX_DEG))
    sign: int = spec(check=_sign)


@dataclass(frozen=True)
class RigRecord:
    """A result's ``rig``: intrinsics, the capture's hand position (mm) and hand angle (deg;
    none: the paper's capture, at φ = 0) and the hand-angle convention."""

    strict: ClassVar[bool] = True

    camera_px: CameraPx
    capture_hand_position_mm: tuple[float, float, float] = spec(check=_each_within(MAX_MM))
    hand_angle: HandAngle = spec()
    capture_hand_angle_deg: float | None = spec(check=_within(MAX_DEG), omit="none",
                                                default=None)  # fmt: skip

    @classmethod
    def of(cls, rig: Rig) -> RigRecord:
        angle = rig.capture_hand_angle_deg
        return cls(
            CameraPx(float(rig.fx_px), float(rig.fy_px), float(rig.cx_px), float(rig.cy_px)),
            tuple(np.asarray(rig.capture_position_mm).tolist()),
            HandAngle(float(rig.angle_zero_deg), int(rig.angle_sign)),
            None if angle is None else float(angle),
        )  # fmt: skip

    def rig(self) -> Rig:
        c = self.camera_px
        return Rig(c.fx, c.fy, c.cx, c.cy, self.capture_hand_position_mm,
                   self.hand_angle.zero_deg, self.hand_angle.sign,
                   self.capture_hand_angle_deg)  # fmt: skip


# -- writing -------------------------------------------------------------------------------


def result_to_document(result: CalibrationResult) -> dict[str, Any]:
    """The result as a JSON-ready document (see the module for its layout)."""
    doc = {
        "format": FORMAT,
        "model": result.model_name,
        "seed": result.settings.seed,
        "settings": result.settings.to_dict(),
        "dataset": result.dataset_name,
        "rig": to_document(RigRecord.of(result.rig)),
        "stage1": to_document(result.stage1),
        "stage2": to_document(result.stage2),
        "centre_index": int(result.centre_index),
        "centres_mm": np.asarray(result.centres_mm).tolist(),
        "timings_s": dict(result.timings_s),
        "sign_twin": {} if result.sign_twin is None else to_document(result.sign_twin),
        "warnings": to_document(result.warnings),
        # The numbers a robot needs, for the NumPy predictor (handeye_jax.robot).
        "frames": result.frames().to_dict(),
    }
    for key in ("recalibration", "deploy", "heights", "search", "diagnostics"):
        value = getattr(result, key)
        if value is not None:
            doc[key] = to_document(value)
    if result.data is not None:
        doc["data"] = dataset_to_document(result.data)
    return doc


def result_to_json(result: CalibrationResult) -> str:
    """The result as ``handeye-jax.result/1`` JSON text, with the digest of its content
    (:data:`~handeye_jax._core.DIGEST_KEY`) by which the NumPy side trusts its frames."""
    doc = json.loads(json.dumps(result_to_document(result), allow_nan=False))  # as read back
    doc[DIGEST_KEY] = document_digest(doc)
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def save_result(result: CalibrationResult, path: str | Path) -> None:
    """Write the result atomically: the file is complete or not written at all; raises
    :class:`~handeye_jax.InputError` naming ``path`` if it cannot be written."""
    write_output(path, result_to_json(result))


# -- reading with validation ----------------------------------------------------------------

#: The top-level sections every result file has.
REQUIRED = ("format", "model", "seed", "rig", "stage1", "stage2", "centre_index", "centres_mm")


@in_float64
def load_result(path: str | Path) -> CalibrationResult:
    """Read and validate a ``handeye-jax.result/1`` file, every section; raises
    :class:`InputError` naming the file and the field of the first thing wrong."""
    path = Path(path)
    return _result_of(Reader(path), load_json(path, MAX_RESULT_BYTES), path)


@in_float64
def result_from_json(text: str, source: str) -> CalibrationResult:
    """A result from its ``handeye-jax.result/1`` JSON text (as :func:`result_to_json` writes
    it), validated as :func:`load_result` validates a file; ``source`` names it in errors."""
    return _result_of(Reader(source), json.loads(text), Path(source))


def _result_of(r: Reader, doc: Any, path: Path) -> CalibrationResult:
    if not isinstance(doc, dict):
        r.fail("", f"must be a JSON object (got {describe(doc)})")
    for key in REQUIRED:
        if key not in doc:
            r.fail(key, "missing")
    model = _model(r, doc)
    rig = read(r, RigRecord, doc["rig"], "rig")
    centres = _centres(r, doc["centres_mm"])
    dataset_name = doc.get("dataset", "")
    if not isinstance(dataset_name, str):
        r.fail("dataset", f"must be a string (got {describe(dataset_name)})")
    data = _data(r, doc, rig, dataset_name, path)
    model_cls = get_model(model)
    n = data.n_rows if data is not None else None
    stage1 = _stage(r, doc, "stage1", model_cls.param_names, n)
    n = n or len(stage1.residuals_mm) or None
    stage2 = _stage(r, doc, "stage2", AffinePair.param_names, n)
    n = n or len(stage2.residuals_mm) or None
    for name in AFFINE_SCALES:
        if stage2.params[name] <= 0:
            r.fail(f"stage2.params.{name}", f"must be > 0, a scale (got {stage2.params[name]})")
    centre_index = _integer(r, doc["centre_index"], "centre_index", 0, None if n is None else n - 1)
    result = CalibrationResult(
        model=model_cls.from_dict(stage1.params), correction=AffinePair.from_dict(stage2.params),
        rig=rig.rig(), centres_mm=np.array(centres), centre_index=centre_index, stage1=stage1,
        stage2=stage2, settings=_settings(r, doc, model), data=data, dataset_name=dataset_name,
        timings_s=_timings(r, doc), sign_twin=_sign_twin(r, doc),
        warnings=_warnings(r, doc),
        diagnostics=_diagnostics(r, doc, n, stage1, stage2, _touched(data)),
        recalibration=_optional(r, doc, "recalibration", Recalibration),
        deploy=_optional(r, doc, "deploy", Deployment),
        heights=_optional(r, doc, "heights", Heights),
        search=_search(r, doc, model_cls),
    )  # fmt: skip
    # Its parts agree (frames, parameters, rig, data, residuals), as predict checks them.
    check_result_document(doc, path, result.frames)
    return result


def _search(r: Reader, doc: dict[str, Any], model_cls) -> SearchReport | None:
    """The ``search`` section: a range for every parameter of both stages, lower < upper."""
    report = _optional(r, doc, "search", SearchReport)
    if report is None:
        return None
    for key, cls in (("stage1", model_cls), ("stage2", AffinePair)):
        ranges = getattr(report, key)
        r.table(ranges, f"search.{key}", cls.param_names)
        for name in cls.param_names:
            lo, hi = ranges[name].lower, ranges[name].upper
            where = f"search.{key}.{name}"
            r.number(lo, f"{where}.lower", limit=MAX_PARAM)
            r.number(hi, f"{where}.upper", limit=MAX_PARAM)
            if not lo < hi:
                r.fail(where, f"must have lower < upper (got {lo}, {hi})")
            if ranges[name].source not in SOURCES:
                r.fail(f"{where}.source", f"must be one of {', '.join(SOURCES)} (got "
                       f"{describe(ranges[name].source)})")  # fmt: skip
    if report.preset not in SEARCH_PRESETS:
        r.fail("search.preset", f"must be one of {', '.join(SEARCH_PRESETS)} (got "
               f"{describe(report.preset)})")  # fmt: skip
    return report


def _model(r: Reader, doc: dict[str, Any]) -> str:
    if doc["format"] != FORMAT:
        r.fail("format", f"expected {FORMAT!r} (got {describe(doc['format'])})")
    model = doc["model"]
    if not isinstance(model, str) or model not in model_registry():
        known = ", ".join(sorted(model_registry()))
        r.fail("model", f"unknown model {describe(model)}; known: {known}")
    _integer(r, doc["seed"], "seed", *SEED_RANGE)
    return model


def _centres(r: Reader, centres: Any) -> list[list[float]]:
    if not isinstance(centres, list) or len(centres) != 2:
        r.fail("centres_mm", f"must be a list of two [x, y] points (got {describe(centres)})")
    return [r.vector(c, f"centres_mm[{i}]", 2, MAX_MM) for i, c in enumerate(centres)]


def _settings(r: Reader, doc: dict[str, Any], model: str):
    table = doc.get("settings", {})
    settings = read_settings(r, table)
    if settings.model != model and isinstance(table, dict) and "model" in table:
        r.fail("settings.model", f"is {settings.model!r}, the result's model {model!r}")
    return settings.__class__(**{**settings.to_dict(), "model": model, "seed": doc["seed"]})


def _timings(r: Reader, doc: dict[str, Any]) -> dict[str, float]:
    timings = _table(r, doc, "timings_s")
    return {key: r.number(value, f"timings_s.{key}") for key, value in timings.items()}


def _sign_twin(r: Reader, doc: dict[str, Any]) -> SignTwin | None:
    twin = _table(r, doc, "sign_twin")  # {} when the model has none
    return read(r, SignTwin, twin, "sign_twin") if twin else None


def _warnings(r: Reader, doc: dict[str, Any]) -> tuple[FitWarning, ...]:
    warnings = doc.get("warnings", [])
    if not isinstance(warnings, list):
        r.fail("warnings", f"must be an array of strings (got {describe(warnings)})")
    return tuple(read(r, FitWarning, w, f"warnings[{i}]") for i, w in enumerate(warnings))


def _optional(r: Reader, doc: dict[str, Any], key: str, cls: type):
    return None if doc.get(key) is None else read(r, cls, doc[key], key)


def _stage(r: Reader, doc: dict[str, Any], key: str, names: tuple[str, ...],
           n: int | None) -> StageResult:  # fmt: skip
    """A stage, every field checked; its parameters exactly ``names``, its residuals one per
    landmark (``n``, if known) in landmark order."""
    s = doc[key]
    if not isinstance(s, dict):
        r.fail(key, f"must be an object (got {describe(s)})")
    if "params" not in s:
        r.fail(f"{key}.params", "missing")
    r.table(s["params"], f"{key}.params", names)
    residuals = s.get("residuals_mm", [])
    if isinstance(residuals, list) and len(residuals) > MAX_LANDMARKS:
        r.fail(f"{key}.residuals_mm", f"has {len(residuals):,} entries; at most "
               f"{MAX_LANDMARKS:,}, one per landmark")  # fmt: skip
    stage = read(r, StageResult, s, key)
    for m, e in enumerate(stage.residuals_mm):
        if e.m != m:
            r.fail(f"{key}.residuals_mm[{m}].m", f"must be {m}: entries are in landmark order "
                   f"(got {e.m})")  # fmt: skip
    if stage.residuals_mm and n is not None and len(stage.residuals_mm) != n:
        r.fail(f"{key}.residuals_mm", f"must have {n} entries, one per landmark (got "
               f"{len(stage.residuals_mm)})")  # fmt: skip
    for name in stage.status:
        if name not in names:
            r.fail(f"{key}.status.{name}", "must be a parameter's free, prior or fixed (got "
                   "an unknown parameter)")  # fmt: skip
    if stage.prior is not None:
        _prior(r, stage.prior, f"{key}.prior", names)
    return stage


def _prior(r: Reader, prior, where: str, names: tuple[str, ...]) -> None:
    """A stage's prior: its parameters', mean's and precision's sizes agree (a recalibration
    from this result reads them)."""
    k = len(prior.names)
    if not all(n in names for n in prior.names):
        r.fail(f"{where}.names", f"must be parameter names (got {list(prior.names)})")
    if len(prior.mean) != k:
        r.fail(f"{where}.mean", f"must be an array of {k} numbers (got an array of "
               f"{len(prior.mean)})")  # fmt: skip
    if len(prior.precision) != k or any(len(row) != k for row in prior.precision):
        r.fail(f"{where}.precision", f"must be a {k} x {k} matrix")
    for j, v in enumerate(prior.mean):
        r.number(v, f"{where}.mean[{j}]", limit=MAX_PARAM)
    r.number(prior.data_scale_mm, f"{where}.data_scale_mm", positive=True, limit=MAX_MM)
    if prior.data_sigma_mm is not None:
        r.number(prior.data_sigma_mm, f"{where}.data_sigma_mm", positive=True, limit=MAX_MM)


def _diagnostics(r: Reader, doc: dict[str, Any], n: int | None, stage1: StageResult,
                 stage2: StageResult, touches: int | None) -> Diagnostics | None:  # fmt: skip
    """The ``diagnostics``, every field checked; each leave-one-out has one entry per touch
    (older files: per row) and its stage its residuals."""
    if "diagnostics" not in doc:
        return None
    touches = n if touches is None else touches
    diag = _table(r, doc, "diagnostics")
    for key, s in (("stage1", stage1), ("stage2", stage2)):
        d = diag.get(key)
        if not isinstance(d, dict) or not isinstance(d.get("loo"), dict):
            continue
        where = f"diagnostics.{key}.loo"
        held = d["loo"].get("held_out_mm")
        if not s.residuals_mm:
            r.fail(f"{key}.residuals_mm", f"missing: {where} compares with it")
        if not isinstance(held, list) or len(held) not in (n, touches):
            r.fail(f"{where}.held_out_mm", f"must be a list of {touches} (one per touch) "
                   f"(got {describe(held)})")  # fmt: skip
    out = read(r, Diagnostics, diag, "diagnostics")
    for key in ("stage1", "stage2"):
        d = getattr(out, key)
        for m, e in enumerate(() if d is None or d.loo is None else d.loo.held_out_mm):
            if e.m != m:
                r.fail(f"diagnostics.{key}.loo.held_out_mm[{m}].m", f"must be {m}: entries "
                       f"are in landmark order (got {e.m})")  # fmt: skip
    return out


def _touched(data: Dataset | None) -> int | None:
    """How many touches a dataset's rows hold (a leave-one-out's entries), or ``None``."""
    if data is None:
        return None
    if data.is_simple() and not data.has_hand_z:
        return data.n_rows
    return len(np.unique(data.rows()[2]))


def _data(r: Reader, doc: dict[str, Any], rig: RigRecord, name: str,
          path: Path) -> Dataset | None:  # fmt: skip
    """The ``data`` section, or an older result's ``observations`` as a dataset."""
    if "data" in doc:
        return dataset_from_document(doc["data"], path, where="data")
    obs = _table(r, doc, "observations")
    if not obs:
        return None
    r.table(obs, "observations", (*LEGACY_OBSERVATIONS, "mm_per_tablet_px"))
    lo, hi = MM_PER_TABLET_PX
    mm = r.number(obs["mm_per_tablet_px"], "observations.mm_per_tablet_px", positive=True,
                  limit=hi, minimum=lo, unit="mm")  # fmt: skip
    n = None
    arrays = {}
    for key, tail in LEGACY_OBSERVATIONS.items():
        where = f"observations.{key}"
        rows = obs[key]
        if not isinstance(rows, list) or not rows or (n is not None and len(rows) != n):
            want = "a non-empty list" if n is None else f"a list of {n} (one per landmark)"
            r.fail(where, f"must be {want} (got {describe(rows)})")
        if len(rows) > MAX_LANDMARKS:
            r.fail(where, f"has {len(rows):,} landmarks; at most {MAX_LANDMARKS:,}")
        n = len(rows)
        limit = _LEGACY_LIMITS[key]
        if tail:
            arrays[key] = [r.vector(row, f"{where}[{i}]", tail[0], limit)
                           for i, row in enumerate(rows)]  # fmt: skip
        else:
            arrays[key] = [r.number(row, f"{where}[{i}]", positive=key == "depth_mm", limit=limit)
                           for i, row in enumerate(rows)]  # fmt: skip
    cam = rig.camera_px
    # Only the tablet pixel's size was recorded: it is 25.4 / ppi * scale, so scale 1 will do.
    return Dataset(
        name=name or path.stem, camera=Camera(cam.fx, cam.fy, cam.cx, cam.cy),
        tablet_ppi=25.4 / mm, tablet_scale=1.0, hand_angle_zero_deg=rig.hand_angle.zero_deg,
        hand_angle_sign=int(rig.hand_angle.sign), search={},
        tablet_px=arrays["tablet_px"], capture_position_mm=list(rig.capture_hand_position_mm),
        image_px=arrays["image_px"], depth_mm=arrays["depth_mm"],
        hand_xy_mm=arrays["hand_xy_mm"], hand_angle_deg=arrays["hand_angle_deg"],
        touch_error_px=arrays["touch_error_px"], version=1,
    )  # fmt: skip


def _table(r: Reader, doc: dict[str, Any], key: str) -> dict[str, Any]:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        r.fail(key, f"must be an object (got {describe(value)})")
    return value


def _integer(r: Reader, x: Any, where: str, low: int | None = None, high: int | None = None):
    if isinstance(x, bool) or not isinstance(x, int):
        r.fail(where, f"must be an integer (got {describe(x)})")
    if low is not None and x < low or high is not None and x > high:
        got = x if len(str(x)) <= 24 else f"an integer of {len(str(abs(x)))} digits"
        if high is None:
            r.fail(where, f"must be at least {low} (got {got})")
        r.fail(where, f"must be {low} to {high} (got {got})")
    return x


# -- the frames of a result file -----------------------------------------------------------

#: How closely a result's stored frames must agree with those its parameters give.
AGREEMENT_TOL = 1e-9


def _frame_numbers(f: Frames) -> np.ndarray:
    """Every number of ``f`` as one vector (undetermined components as NaN)."""
    parts = [f.R_hand_camera, f.R_base_tablet, f.capture_position_mm, f.centres_mm,
             f.A1.as_tuple(), f.A2.as_tuple(), f.camera_px,
             (f.hand_angle_zero_deg, f.hand_angle_sign, f.capture_hand_angle_deg,
              math.nan if f.pen_minus_camera_z_mm is None else f.pen_minus_camera_z_mm),
             f.distortion or (math.nan,) * 5,
             *(getattr(f, t) for t in TRANSLATIONS)]  # fmt: skip
    return np.concatenate([np.ravel(np.asarray(p, dtype=np.float64)) for p in parts])


def load_frames(path: str | Path) -> Frames:
    """A result file's frames: validated with :func:`~handeye_jax.load_result`, computed from
    its parameters, and checked against the file's own ``frames`` section when it has one.

    Older results, without the section, load. A section that disagrees with the parameters
    (a hand-edited file) is an :class:`InputError`: the NumPy predictor reads the section, the
    JAX path the parameters, and they must not give different hand commands.
    """
    result = load_result(path)
    frames = result.frames()
    doc = read_json(path)
    if "frames" not in doc:
        return frames
    stored = Frames.from_dict(doc["frames"], path, "frames")
    a, b = _frame_numbers(stored), _frame_numbers(frames)
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    if set(stored.undetermined) != set(frames.undetermined) or (nan_a != nan_b).any():
        raise InputError(path, "frames.undetermined", f"must list {', '.join(UNDETERMINED)} "
                         "as the parameters leave them")  # fmt: skip
    scale = np.maximum(1.0, np.abs(b[~nan_b]))
    err = float((np.abs(a[~nan_a] - b[~nan_b]) / scale).max())
    if err > AGREEMENT_TOL:
        raise InputError(path, "frames", f"disagrees with the parameters (stage1.params, "
                         f"stage2.params, rig, centres_mm) by {err:.3g}: the file was edited; "
                         "delete the frames section to use the parameters")  # fmt: skip
    return stored
