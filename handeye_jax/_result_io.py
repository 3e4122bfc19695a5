"""Result files: ``handeye-jax.result/1`` (JSON), written and read with every field checked.

The layout (every section but the first nine is optional; older files load)::

    format, model, seed, settings{...}, dataset, timings_s{stage1_de, ..., total}
    rig{camera_px{fx,fy,cx,cy}, capture_hand_position_mm, hand_angle{zero_deg, sign}}
    stage1, stage2: {F, f1, f2, params{name: value}, residuals_mm[...], de{...}, polish{...},
                     convergence{...}, status{name: free|prior|fixed}, fixed_source{...},
                     prior{source, names, mean, precision, data_scale_mm, data_sigma_mm?,
                           pulls[...]}, prior_F}
    centre_index, centres_mm[[x, y], [x, y]], sign_twin{...}, warnings[]
    frames{...}                 # the fitted frames as numbers, for the NumPy predictor
    content_sha256              # of all the rest: while it matches, the frames need no check
    recalibration{previous, refit[], others}
    diagnostics{...}
    data{...}                   # the dataset fitted, as its own file's document (v1 or v2)
    observations{...}           # older results: the landmark arrays instead of ``data``

The data section is read by the dataset's own reader (:mod:`._dataset_io`): one schema.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import write_output
from ._dataset import Camera, Dataset
from ._dataset_io import dataset_from_document, dataset_to_document
from ._io import DIGEST_KEY, MAX_RESULT_BYTES, document_digest, load_json
from ._observations import Rig
from ._params import FIXED, FREE, PRIOR
from ._result import CalibrationResult, StageResult
from ._settings import SEED_RANGE, read_settings
from ._trust import check_result_document
from ._validate import (
    MAX_DEG,
    MAX_LANDMARKS,
    MAX_MM,
    MAX_PX,
    MM_PER_TABLET_PX,
    Reader,
    describe,
    join_key,
)
from ._x64 import in_float64
from .models import AffinePair, get_model, model_registry

FORMAT = "handeye-jax.result/1"
#: Stage-2 parameters that are scale factors (> 0: zero collapses the plane, < 0 mirrors it).
AFFINE_SCALES = ("Sx1", "Sy1", "Sx2", "Sy2")
#: Largest magnitude of a fitted parameter: the widest search range a dataset admits (DE and
#: the LM polish stay inside their range).
MAX_PARAM = 1e6
RESIDUAL_KEYS = ("m", "image_vs_tablet_xy_mm", "image_vs_tablet_mm", "hand_xy_mm", "hand_mm")
LOO_KEYS = ("held_out_mm", "f1", "f2", "F", "in_sample_F")
HELD_OUT_KEYS = ("m", "image_vs_tablet_mm", "hand_mm")
#: The landmark arrays of an older result's ``observations``: name → shape after the row.
LEGACY_OBSERVATIONS: dict[str, tuple[int, ...]] = {
    "tablet_px": (2,), "image_px": (2,), "depth_mm": (), "hand_xy_mm": (2,),
    "hand_angle_deg": (), "touch_error_px": (2,),
}  # fmt: skip
_LEGACY_LIMITS = {
    "tablet_px": MAX_PX, "image_px": MAX_PX, "depth_mm": MAX_MM, "hand_xy_mm": MAX_MM,
    "hand_angle_deg": MAX_DEG, "touch_error_px": MAX_PX,
}  # fmt: skip


# -- writing -------------------------------------------------------------------------------


def rig_to_dict(rig: Rig) -> dict[str, Any]:
    out = {
        "camera_px": {
            "fx": float(rig.fx_px), "fy": float(rig.fy_px),
            "cx": float(rig.cx_px), "cy": float(rig.cy_px),
        },
        "capture_hand_position_mm": np.asarray(rig.capture_position_mm).tolist(),
        "hand_angle": {"zero_deg": float(rig.angle_zero_deg), "sign": int(rig.angle_sign)},
    }  # fmt: skip
    if rig.capture_hand_angle_deg is not None:  # else the paper's capture, at φ = 0
        out["capture_hand_angle_deg"] = float(rig.capture_hand_angle_deg)
    return out


def _stage_doc(s: StageResult) -> dict[str, Any]:
    out = {
        "F": s.F, "f1": s.f1, "f2": s.f2, "params": s.params,
        "residuals_mm": s.residuals_mm, "de": s.de, "polish": s.polish,
        "convergence": s.convergence, "status": s.status,
    }  # fmt: skip
    if s.fixed_source:
        out["fixed_source"] = s.fixed_source
    if s.prior is not None:
        out["prior"], out["prior_F"] = s.prior, s.prior_F
    return out


def result_to_document(result: CalibrationResult) -> dict[str, Any]:
    """The result as a JSON-ready document."""
    doc = {
        "format": FORMAT,
        "model": result.model_name,
        "seed": result.settings.seed,
        "settings": result.settings.to_dict(),
        "dataset": result.dataset_name,
        "rig": rig_to_dict(result.rig),
        "stage1": _stage_doc(result.stage1),
        "stage2": _stage_doc(result.stage2),
        "centre_index": int(result.centre_index),
        "centres_mm": np.asarray(result.centres_mm).tolist(),
        "timings_s": result.timings_s,
        "sign_twin": result.sign_twin,
        "warnings": result.warnings,
        # The numbers a robot needs, for the NumPy predictor (handeye_jax._predictor).
        "frames": result.frames().to_dict(),
    }
    if result.recalibration:
        doc["recalibration"] = result.recalibration
    if result.heights:
        doc["heights"] = result.heights
    if result.diagnostics:
        doc["diagnostics"] = result.diagnostics
    if result.data is not None:
        doc["data"] = dataset_to_document(result.data)
    return doc


def result_to_json(result: CalibrationResult) -> str:
    """The result as ``handeye-jax.result/1`` JSON text, with the digest of its content
    (:data:`~handeye_jax._io.DIGEST_KEY`) by which the NumPy side trusts its frames."""
    doc = json.loads(json.dumps(result_to_document(result), allow_nan=False))  # as read back
    doc[DIGEST_KEY] = document_digest(doc)
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def save_result(result: CalibrationResult, path: str | Path) -> None:
    """Write the result atomically: the file is complete or not written at all; raises
    :class:`~handeye_jax.InputError` naming ``path`` if it cannot be written."""
    write_output(path, result_to_json(result))


# -- reading with validation ----------------------------------------------------------------


def rig_from_dict(d: dict[str, Any]) -> Rig:
    cam = d["camera_px"]
    return Rig(
        cam["fx"], cam["fy"], cam["cx"], cam["cy"],
        d["capture_hand_position_mm"], d["hand_angle"]["zero_deg"], d["hand_angle"]["sign"],
        d.get("capture_hand_angle_deg"),
    )  # fmt: skip


@in_float64
def load_result(path: str | Path) -> CalibrationResult:
    """Read and validate a ``handeye-jax.result/1`` file; raises :class:`InputError`.

    Every field that prediction, the report and the evaluation use is checked, so a file
    that loads can be used; unknown top-level keys and the parts of ``diagnostics`` only the
    calibration summary prints are not.
    """
    path = Path(path)
    r = Reader(path)
    doc = load_json(path, MAX_RESULT_BYTES)
    if not isinstance(doc, dict):
        r.fail("", f"must be a JSON object (got {describe(doc)})")
    for key in ("format", "model", "seed", "rig", "stage1", "stage2", "centre_index",
                "centres_mm"):  # fmt: skip
        _field(r, doc, key, "")
    if doc["format"] != FORMAT:
        r.fail("format", f"expected {FORMAT!r} (got {describe(doc['format'])})")
    model = doc["model"]
    if not isinstance(model, str) or model not in model_registry():
        known = ", ".join(sorted(model_registry()))
        r.fail("model", f"unknown model {describe(model)}; known: {known}")
    seed = _integer(r, doc["seed"], "seed", *SEED_RANGE)
    rig_doc = _rig(r, doc["rig"])
    centres = doc["centres_mm"]
    if not isinstance(centres, list) or len(centres) != 2:
        r.fail("centres_mm", f"must be a list of two [x, y] points (got {describe(centres)})")
    centres = [r.vector(c, f"centres_mm[{i}]", 2, MAX_MM) for i, c in enumerate(centres)]
    dataset_name = doc.get("dataset", "")
    if not isinstance(dataset_name, str):
        r.fail("dataset", f"must be a string (got {describe(dataset_name)})")
    data = _data(r, doc, rig_doc, dataset_name, path)
    model_cls = get_model(model)
    stage1 = _stage(r, doc, "stage1", model_cls.param_names)
    stage2 = _stage(r, doc, "stage2", AffinePair.param_names)
    for name in AFFINE_SCALES:
        if stage2.params[name] <= 0:
            r.fail(f"stage2.params.{name}", f"must be > 0, a scale (got {stage2.params[name]})")
    n = data.n_rows if data is not None else None
    for key, s in (("stage1", stage1), ("stage2", stage2)):
        n = n or len(s.residuals_mm) or None
        if s.residuals_mm and len(s.residuals_mm) != n:
            r.fail(f"{key}.residuals_mm", f"must have {n} entries, one per landmark (got "
                   f"{len(s.residuals_mm)})")  # fmt: skip
    centre_index = _integer(r, doc["centre_index"], "centre_index", 0, None if n is None else n - 1)
    settings = read_settings(r, _optional_table(r, doc, "settings"))
    if settings.model != model and "model" in doc.get("settings", {}):
        r.fail("settings.model", f"is {settings.model!r}, the result's model {model!r}")
    settings = settings.__class__(**{**settings.to_dict(), "model": model, "seed": seed})
    timings = _optional_table(r, doc, "timings_s")
    for key, value in timings.items():
        r.number(value, f"timings_s.{key}")
    warnings = doc.get("warnings", [])
    if not isinstance(warnings, list):
        r.fail("warnings", f"must be an array of strings (got {describe(warnings)})")
    for i, w in enumerate(warnings):
        if not isinstance(w, str):
            r.fail(f"warnings[{i}]", f"must be a string (got {describe(w)})")
    recal = doc.get("recalibration")
    if recal is not None and not isinstance(recal, dict):
        r.fail("recalibration", f"must be an object (got {describe(recal)})")
    result = CalibrationResult(
        model=model_cls.from_dict(stage1.params),
        correction=AffinePair.from_dict(stage2.params),
        rig=rig_from_dict(rig_doc),
        centres_mm=np.array(centres),
        centre_index=centre_index,
        stage1=stage1,
        stage2=stage2,
        settings=settings,
        data=data,
        dataset_name=dataset_name,
        timings_s=timings,
        sign_twin=_optional_table(r, doc, "sign_twin"),
        warnings=warnings,
        diagnostics=_diagnostics(r, doc, n, (stage1, stage2)),
        recalibration=recal,
        heights=_heights(r, doc),
    )
    # Its parts agree (frames, parameters, rig, data, residuals), as predict checks them.
    check_result_document(doc, path, result.frames)
    return result


#: The keys of a result's ``heights`` (what the hand's heights at the touches determined).
HEIGHT_KEYS = ("pen_minus_camera_mm", "tablet_plus_camera_mm", "tablet_plus_pen_mm",
               "pen_minus_camera_sigma_mm", "f1z_mm", "f2z_mm", "n_views", "n_touches")  # fmt: skip


def _heights(r: Reader, doc: dict[str, Any]) -> dict[str, float] | None:
    if "heights" not in doc:
        return None
    h = r.table(doc["heights"], "heights", HEIGHT_KEYS)
    return {k: r.number(h[k], f"heights.{k}", limit=MAX_MM) for k in HEIGHT_KEYS}


def _data(r: Reader, doc: dict[str, Any], rig: dict, name: str, path: Path) -> Dataset | None:
    """The ``data`` section, or an older result's ``observations`` as a dataset."""
    if "data" in doc:
        return dataset_from_document(doc["data"], path, where="data")
    obs = _optional_table(r, doc, "observations")
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
    cam = rig["camera_px"]
    # Only the tablet pixel's size was recorded: it is 25.4 / ppi * scale, so scale 1 will do.
    return Dataset(
        name=name or path.stem, camera=Camera(cam["fx"], cam["fy"], cam["cx"], cam["cy"]),
        tablet_ppi=25.4 / mm, tablet_scale=1.0,
        hand_angle_zero_deg=rig["hand_angle"]["zero_deg"],
        hand_angle_sign=int(rig["hand_angle"]["sign"]), search={},
        tablet_px=arrays["tablet_px"], capture_position_mm=rig["capture_hand_position_mm"],
        image_px=arrays["image_px"], depth_mm=arrays["depth_mm"],
        hand_xy_mm=arrays["hand_xy_mm"], hand_angle_deg=arrays["hand_angle_deg"],
        touch_error_px=arrays["touch_error_px"], version=1,
    )  # fmt: skip


def _field(r: Reader, table: dict[str, Any], key: str, where: str) -> Any:
    if key not in table:
        r.fail(join_key(where, key), "missing")
    return table[key]


def _integer(r: Reader, x: Any, where: str, low: int | None = None, high: int | None = None):
    if isinstance(x, bool) or not isinstance(x, int):
        r.fail(where, f"must be an integer (got {describe(x)})")
    if low is not None and x < low or high is not None and x > high:
        got = x if len(str(x)) <= 24 else f"an integer of {len(str(abs(x)))} digits"
        if high is None:
            r.fail(where, f"must be at least {low} (got {got})")
        r.fail(where, f"must be {low} to {high} (got {got})")
    return x


def _count(r: Reader, x: Any, where: str) -> int:
    return _integer(r, x, where, 0)


def _boolean(r: Reader, x: Any, where: str) -> bool:
    if not isinstance(x, bool):
        r.fail(where, f"must be true or false (got {describe(x)})")
    return x


def _string(r: Reader, x: Any, where: str) -> str:
    if not isinstance(x, str):
        r.fail(where, f"must be a string (got {describe(x)})")
    return x


def _length(r: Reader, x: Any, where: str) -> float:
    """An error length or a mean of them, mm: finite and >= 0."""
    v = r.number(x, where)
    if v < 0:
        r.fail(where, f"must be >= 0 mm (got {v})")
    return v


def _numbers(r: Reader, x: Any, where: str) -> list[float]:
    if not isinstance(x, list):
        r.fail(where, f"must be an array of numbers (got {describe(x)})")
    return [r.number(v, f"{where}[{i}]") for i, v in enumerate(x)]


#: Checks of the DE and LM summaries of a stage, by key; other keys are kept unchecked.
_DE = {"F": Reader.number, "generations": _count, "evaluations": _count, "converged": _boolean}
_POLISH = {
    "ran": _boolean, "accepted": _boolean, "F_before": Reader.number, "F_after": Reader.number,
    "steps": _count, "solver_converged": _boolean,
}  # fmt: skip


def _rig(r: Reader, value: Any) -> dict[str, Any]:
    rig = r.table(value, "rig", ("camera_px", "capture_hand_position_mm", "hand_angle"),
                  optional=("capture_hand_angle_deg",))  # fmt: skip
    if "capture_hand_angle_deg" in rig:
        r.number(rig["capture_hand_angle_deg"], "rig.capture_hand_angle_deg", limit=MAX_DEG)
    cam = r.table(rig["camera_px"], "rig.camera_px", ("fx", "fy", "cx", "cy"))
    for k in ("fx", "fy"):
        r.number(cam[k], f"rig.camera_px.{k}", True, MAX_PX, minimum=1, unit="px")
    for k in ("cx", "cy"):
        r.number(cam[k], f"rig.camera_px.{k}", limit=MAX_PX)
    r.vector(rig["capture_hand_position_mm"], "rig.capture_hand_position_mm", 3, MAX_MM)
    angle = r.table(rig["hand_angle"], "rig.hand_angle", ("zero_deg", "sign"))
    r.number(angle["zero_deg"], "rig.hand_angle.zero_deg", limit=MAX_DEG)
    if r.number(angle["sign"], "rig.hand_angle.sign") not in (1.0, -1.0):
        r.fail("rig.hand_angle.sign", f"must be 1 or -1 (got {angle['sign']})")
    return rig


def _stage(r: Reader, doc: dict[str, Any], key: str, names: tuple[str, ...]) -> StageResult:
    s = doc[key]
    if not isinstance(s, dict):
        r.fail(key, f"must be an object (got {describe(s)})")
    F, f1, f2 = (_length(r, _field(r, s, k, key), f"{key}.{k}") for k in ("F", "f1", "f2"))
    p = r.table(_field(r, s, "params", key), f"{key}.params", names)
    params = {n: r.number(p[n], f"{key}.params.{n}", limit=MAX_PARAM) for n in names}
    residuals = s.get("residuals_mm", [])
    if not isinstance(residuals, list):
        r.fail(f"{key}.residuals_mm", f"must be an array, one entry per landmark (got "
               f"{describe(residuals)})")  # fmt: skip
    if len(residuals) > MAX_LANDMARKS:
        r.fail(f"{key}.residuals_mm", f"has {len(residuals):,} entries; at most "
               f"{MAX_LANDMARKS:,}, one per landmark")  # fmt: skip
    for m, e in enumerate(residuals):
        _residual(r, e, f"{key}.residuals_mm[{m}]", m, RESIDUAL_KEYS)
    de = _summary(r, s, "de", key, _DE)
    polish = _summary(r, s, "polish", key, _POLISH)
    if "pinned" in polish:  # the first results listed the parameters LM left on a bound
        pinned = polish["pinned"]
        if not isinstance(pinned, list) or not all(isinstance(p, str) for p in pinned):
            r.fail(f"{key}.polish.pinned", f"must be an array of names (got {describe(pinned)})")
    status = _optional_table(r, s, "status", key)
    for n, st in status.items():
        if n not in names or st not in (FREE, PRIOR, FIXED):
            r.fail(f"{key}.status.{n}", f"must be a parameter's free, prior or fixed (got "
                   f"{describe(st)})")  # fmt: skip
    fixed_source = _optional_table(r, s, "fixed_source", key)
    prior = s.get("prior")
    if prior is not None:
        prior = _prior(r, prior, f"{key}.prior", names)
    prior_F = s.get("prior_F")
    if prior_F is not None:
        prior_F = _length(r, prior_F, f"{key}.prior_F")
    return StageResult(
        F=F, f1=f1, f2=f2, params=params, residuals_mm=residuals, de=de, polish=polish,
        convergence=_convergence(r, s, key), status=status, fixed_source=fixed_source,
        prior=prior, prior_F=prior_F,
    )  # fmt: skip


def _prior(r: Reader, p: Any, where: str, names: tuple[str, ...]) -> dict[str, Any]:
    """A stage's ``prior``: its parameters, mean and precision, checked (a recalibration
    from this result reads them)."""
    if not isinstance(p, dict):
        r.fail(where, f"must be an object (got {describe(p)})")
    for key in ("source", "names", "mean", "precision", "data_scale_mm"):
        _field(r, p, key, where)
    got = p["names"]
    if not isinstance(got, list) or not all(isinstance(n, str) and n in names for n in got):
        r.fail(f"{where}.names", f"must be parameter names (got {describe(got)})")
    k = len(got)
    r.vector(p["mean"], f"{where}.mean", k, MAX_PARAM)
    P = p["precision"]
    if not isinstance(P, list) or len(P) != k:
        r.fail(f"{where}.precision", f"must be a {k} x {k} matrix (got {describe(P)})")
    for i, row in enumerate(P):
        r.vector(row, f"{where}.precision[{i}]", k)
    r.number(p["data_scale_mm"], f"{where}.data_scale_mm", positive=True, limit=MAX_MM)
    if "data_sigma_mm" in p:
        r.number(p["data_sigma_mm"], f"{where}.data_sigma_mm", positive=True, limit=MAX_MM)
    return p


def _residual(r: Reader, e: Any, where: str, m: int, keys: tuple[str, ...]) -> None:
    """One landmark's entry of ``residuals_mm`` or of a leave-one-out's ``held_out_mm``."""
    r.table(e, where, keys)
    if _integer(r, e["m"], f"{where}.m") != m:
        r.fail(f"{where}.m", f"must be {m}: entries are in landmark order (got {e['m']})")
    for k in keys[1:]:
        if k.endswith("_xy_mm"):
            r.vector(e[k], f"{where}.{k}", 2)
        else:
            _length(r, e[k], f"{where}.{k}")


def _summary(r: Reader, s: dict[str, Any], key: str, stage: str, checks: dict) -> dict[str, Any]:
    where = f"{stage}.{key}"
    value = s.get(key, {})
    if not isinstance(value, dict):
        r.fail(where, f"must be an object (got {describe(value)})")
    for k, check in checks.items():
        if k in value:
            check(r, value[k], f"{where}.{k}")
    return value


def _convergence(r: Reader, s: dict[str, Any], stage: str) -> dict[str, list[float]]:
    where = f"{stage}.convergence"
    c = s.get("convergence", {})
    if not isinstance(c, dict):
        r.fail(where, f"must be an object (got {describe(c)})")
    out = dict(c)
    for k in ("best_F", "median_F"):
        if k in c:
            out[k] = _numbers(r, c[k], f"{where}.{k}")
    if "median_generation" in c:
        gens = c["median_generation"]
        if not isinstance(gens, list):
            r.fail(f"{where}.median_generation", f"must be an array of generations (got "
                   f"{describe(gens)})")  # fmt: skip
        for i, g in enumerate(gens):
            _integer(r, g, f"{where}.median_generation[{i}]", 1)
        if "median_F" in c and len(gens) != len(c["median_F"]):
            r.fail(f"{where}.median_generation", f"must have one generation per median_F "
                   f"({len(c['median_F'])}) (got {len(gens)})")  # fmt: skip
    elif "median_F" in c:  # the first results recorded it every generation
        out["median_generation"] = list(range(1, len(c["median_F"]) + 1))
    return out


def _optional_table(r: Reader, doc: dict[str, Any], key: str, where: str = "") -> dict[str, Any]:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        r.fail(join_key(where, key), f"must be an object (got {describe(value)})")
    return value


def _diagnostics(
    r: Reader, doc: dict[str, Any], n: int | None, stages: tuple[StageResult, StageResult]
) -> dict[str, Any]:
    """The optional ``diagnostics``: each stage's object and its leave-one-out are checked."""
    diag = _optional_table(r, doc, "diagnostics")
    for key, s in zip(("stage1", "stage2"), stages, strict=True):
        if key not in diag:
            continue
        d = diag[key]
        where = f"diagnostics.{key}"
        if not isinstance(d, dict):
            r.fail(where, f"must be an object (got {describe(d)})")
        if "loo" not in d:
            continue
        loo = r.table(d["loo"], f"{where}.loo", LOO_KEYS)
        for k in LOO_KEYS[1:]:
            _length(r, loo[k], f"{where}.loo.{k}")
        held = loo["held_out_mm"]
        if not s.residuals_mm:
            r.fail(f"{key}.residuals_mm", f"missing: {where}.loo compares with it")
        if not isinstance(held, list) or len(held) != n:
            r.fail(f"{where}.loo.held_out_mm", f"must be a list of {n} (one per landmark) "
                   f"(got {describe(held)})")  # fmt: skip
        for m, e in enumerate(held):
            _residual(r, e, f"{where}.loo.held_out_mm[{m}]", m, HELD_OUT_KEYS)
    return diag
