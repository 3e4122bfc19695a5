"""The calibration result and its file format, ``handeye-jax.result/1`` (JSON).

A result is self-contained: with the rig it was fitted on (intrinsics, capture pose, hand-angle
convention) it predicts hand commands without the dataset.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._atomic import write_output
from ._frames import Frames
from ._io import MAX_RESULT_BYTES, load_json
from ._params import Prior
from ._validate import (
    MAX_DEG,
    MAX_GENERATIONS,
    MAX_LANDMARKS,
    MAX_MM,
    MAX_POPULATION,
    MAX_PX,
    MAX_RESTARTS,
    MM_PER_TABLET_PX,
    Reader,
    describe,
    join_key,
)
from ._x64 import in_float64
from .errors import InputError
from .frames import compute_frames
from .losses import LOSS_NAMES
from .models import AbstractCorrection, AbstractModel, AffinePair, get_model, model_registry
from .observations import Rig
from .predict import hand_command

if TYPE_CHECKING:
    from ._dataset import Dataset

FORMAT = "handeye-jax.result/1"


@dataclass(frozen=True)
class StageResult:
    """One stage's optimum.

    Attributes:
        F, f1, f2: the fitness and its two terms, mm.
        params: parameter name → value (mm, deg or 1, as the model's ``param_units`` say).
        residuals_mm: per landmark, the error vectors and lengths of both terms, mm.
        de: DE summary (generations, evaluations, converged, F found by DE).
        polish: LM summary (accepted, F before and after, steps, parameters pinned to a bound).
        convergence: best and median F after each DE generation, mm.
    """

    F: float
    f1: float
    f2: float
    params: dict[str, float]
    residuals_mm: list[dict[str, Any]]
    de: dict[str, Any]
    polish: dict[str, Any]
    convergence: dict[str, list[float]] = field(default_factory=dict)
    status: dict[str, str] = field(default_factory=dict)
    fixed_source: dict[str, str] = field(default_factory=dict)
    prior: dict[str, Any] | None = None
    prior_F: float | None = None

    def __post_init__(self):
        if not self.status:  # every parameter free: the paper's fit, and every older result
            object.__setattr__(self, "status", dict.fromkeys(self.params, "free"))

    def free(self) -> tuple[str, ...]:
        """The parameters the fit moved (free or with a prior), in ``params`` order."""
        return tuple(n for n in self.params if self.status.get(n, "free") != "fixed")


@dataclass(frozen=True)
class CalibrationResult:
    """Everything a calibration produced, and what is needed to use it."""

    model: str
    seed: int
    settings: dict[str, Any]
    dataset: str
    rig: dict[str, Any]
    stage1: StageResult
    stage2: StageResult
    centre_index: int
    centres_mm: list[list[float]]
    timings_s: dict[str, float]
    sign_twin: dict[str, Any]
    warnings: list[str]
    diagnostics: dict[str, Any] = field(default_factory=dict)
    observations: dict[str, Any] = field(default_factory=dict)
    recalibration: dict[str, Any] | None = None
    format: str = FORMAT
    #: The stages' fits in memory (objectives, final DE populations), for the diagnostics of a
    #: result that was just computed; not written to the file.
    fits: tuple[Any, Any] | None = field(default=None, compare=False, repr=False)

    # -- use -----------------------------------------------------------------------------
    @in_float64
    def fitted_model(self) -> AbstractModel:
        """The stage-1 model as a JAX pytree (float64 leaves)."""
        return get_model(self.model).from_dict(self.stage1.params)

    @in_float64
    def fitted_correction(self) -> AbstractCorrection:
        """The stage-2 correction as a JAX pytree."""
        return AffinePair.from_dict(self.stage2.params)

    @in_float64
    def fitted_rig(self) -> Rig:
        """The rig the result was fitted on (intrinsics, capture pose, angle convention)."""
        return rig_from_dict(self.rig)

    @in_float64
    def predict(
        self,
        image_px: Float[Array, "n 2"],
        depth_mm: Float[Array, " n"],
        hand_angle_deg: Float[Array, " n"],
        stage: int = 2,
    ) -> np.ndarray:
        """Hand commands ``(x, y)`` in mm for image points, eq. (25) (stage 2) or (8) (stage 1)."""
        if stage not in (1, 2):
            raise ValueError(f"stage must be 1 or 2 (got {stage})")
        out = hand_command(
            self.fitted_model(),
            self.fitted_rig(),
            jnp.asarray(image_px, dtype=float),
            jnp.asarray(depth_mm, dtype=float),
            jnp.asarray(hand_angle_deg, dtype=float),
            correction=self.fitted_correction() if stage == 2 else None,
            centres_mm=jnp.asarray(self.centres_mm, dtype=float),
        )
        return np.asarray(out)

    @in_float64
    def posterior(self, stage: str = "stage1", source: str | None = None) -> Prior:
        """The fit's Gaussian posterior of a stage's free parameters (Gauss–Newton at the
        optimum, its prior included): what a recalibration takes as its prior.

        Taken from the diagnostics' ``precision`` when present, else computed from the
        result's observations.
        """
        s: StageResult = getattr(self, stage)
        free = s.free()
        diag = self.diagnostics.get(stage, {}) if self.diagnostics else {}
        P = diag.get("precision")
        if P is None or np.shape(P) != (len(free), len(free)):
            P = self._posterior_precision(stage, free)
        return Prior(free, [s.params[n] for n in free], np.asarray(P, dtype=float),
                     source or f"previous result ({self.dataset})",
                     max(s.F, 1e-6) / 4.0)  # fmt: skip

    def _posterior_precision(self, stage: str, free: tuple[str, ...]) -> np.ndarray:
        from ._objective import Stage1Objective, Stage2Objective, chain_points
        from .identifiability import analyse_jacobian, error_jacobian

        if not self.observations:
            raise InputError(None, "observations", "the result does not carry its data, so "
                             "its posterior cannot be computed; calibrate again")  # fmt: skip
        obs = observations_from_dict(self.observations, self.fitted_rig(), self.centre_index)
        s: StageResult = getattr(self, stage)
        model = self.fitted_model()
        if stage == "stage1":
            objective = Stage1Objective(model, obs, free)
        else:
            points = chain_points(model, obs)
            objective = Stage2Objective(self.fitted_correction(), points, self.centre_index, free)
        x = jnp.asarray([s.params[n] for n in free])
        e, J = (np.asarray(a) for a in error_jacobian(objective, x))
        P_prior = None
        if s.prior:
            P_prior = np.zeros((len(free), len(free)))
            idx = [free.index(n) for n in s.prior["names"]]
            P_prior[np.ix_(idx, idx)] = np.asarray(s.prior["precision"])
        out = analyse_jacobian(e, J, free, ["1"] * len(free), None, P_prior)
        return np.asarray(out["precision"])

    def frames(self) -> Frames:
        """The fitted frames as plain numbers (NumPy), from the parameters and the rig."""
        return compute_frames(
            self.fitted_model(), self.fitted_rig(), self.fitted_correction(), self.centres_mm
        )

    # -- files ---------------------------------------------------------------------------
    def to_json(self) -> str:
        def stage(s: StageResult) -> dict[str, Any]:
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

        doc = {
            "format": self.format,
            "model": self.model,
            "seed": self.seed,
            "settings": self.settings,
            "dataset": self.dataset,
            "rig": self.rig,
            "stage1": stage(self.stage1),
            "stage2": stage(self.stage2),
            "centre_index": self.centre_index,
            "centres_mm": self.centres_mm,
            "timings_s": self.timings_s,
            "sign_twin": self.sign_twin,
            "warnings": self.warnings,
            # The numbers a robot needs, for the NumPy predictor (handeye_jax._predictor).
            "frames": self.frames().to_dict(),
        }
        if self.recalibration:
            doc["recalibration"] = self.recalibration
        # Optional sections (older results lack them): see handeye_jax.diagnostics.
        if self.diagnostics:
            doc["diagnostics"] = self.diagnostics
        if self.observations:
            doc["observations"] = self.observations
        return json.dumps(doc, indent=2, allow_nan=False) + "\n"

    def save(self, path: str | Path) -> None:
        """Write the result atomically: the file is complete or not written at all; raises
        :class:`InputError` naming ``path`` if it cannot be written."""
        write_output(path, self.to_json())


def rig_to_dict(rig: Rig) -> dict[str, Any]:
    return {
        "camera_px": {
            "fx": float(rig.fx_px), "fy": float(rig.fy_px),
            "cx": float(rig.cx_px), "cy": float(rig.cy_px),
        },
        "capture_hand_position_mm": np.asarray(rig.capture_position_mm).tolist(),
        "hand_angle": {"zero_deg": float(rig.angle_zero_deg), "sign": int(rig.angle_sign)},
    }  # fmt: skip


#: The landmark data a result carries for its figures: name → shape after the landmark axis.
OBSERVATION_ARRAYS: dict[str, tuple[int, ...]] = {
    "tablet_px": (2,), "image_px": (2,), "depth_mm": (), "hand_xy_mm": (2,),
    "hand_angle_deg": (), "touch_error_px": (2,),
}  # fmt: skip


def observations_to_dict(dataset: Dataset) -> dict[str, Any]:
    """The dataset's landmark arrays (px, mm, deg) and tablet pixel size, as JSON lists."""
    doc: dict[str, Any] = {k: np.asarray(getattr(dataset, k)).tolist() for k in OBSERVATION_ARRAYS}
    doc["mm_per_tablet_px"] = float(dataset.mm_per_tablet_px)
    return doc


def observations_from_dict(o: dict[str, Any], rig: Rig, centre_index: int | None = None):
    """The :class:`~handeye_jax.Observations` of a result's ``observations`` section."""
    from .observations import Observations, centre_landmark

    mm = float(o["mm_per_tablet_px"])
    arr = {k: jnp.asarray(np.asarray(o[k], dtype=float)) for k in o if k != "mm_per_tablet_px"}
    if centre_index is None:
        centre_index = centre_landmark(np.asarray(o["tablet_px"], dtype=float))
    return Observations(
        rig=rig,
        image_px=arr["image_px"],
        depth_mm=arr["depth_mm"],
        tablet_mm=arr["tablet_px"] * mm,
        hand_xy_mm=arr["hand_xy_mm"],
        hand_angle_deg=arr["hand_angle_deg"],
        touch_error_mm=arr["touch_error_px"] * mm,
        centre_index=centre_index,
    )


def rig_from_dict(d: dict[str, Any]) -> Rig:
    cam = d["camera_px"]
    return Rig(
        cam["fx"], cam["fy"], cam["cx"], cam["cy"],
        d["capture_hand_position_mm"], d["hand_angle"]["zero_deg"], d["hand_angle"]["sign"],
    )  # fmt: skip


# -- loading with validation ---------------------------------------------------------------

#: Stage-2 parameters that are scale factors (> 0: zero collapses the plane, < 0 mirrors it).
AFFINE_SCALES = ("Sx1", "Sy1", "Sx2", "Sy2")
#: Largest magnitude of a fitted parameter: the widest search range a dataset admits (DE and
#: the LM polish stay inside their range).
MAX_PARAM = 1e6
#: Largest magnitude of each landmark array of ``observations``.
OBSERVATION_LIMITS = {
    "tablet_px": MAX_PX, "image_px": MAX_PX, "depth_mm": MAX_MM, "hand_xy_mm": MAX_MM,
    "hand_angle_deg": MAX_DEG, "touch_error_px": MAX_PX,
}  # fmt: skip
RESIDUAL_KEYS = ("m", "image_vs_tablet_xy_mm", "image_vs_tablet_mm", "hand_xy_mm", "hand_mm")
LOO_KEYS = ("held_out_mm", "f1", "f2", "F", "in_sample_F")
HELD_OUT_KEYS = ("m", "image_vs_tablet_mm", "hand_mm")
SEED_RANGE = (-(2**63), 2**63 - 1)


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
    model = _model_name(r, doc["model"], "model")
    seed = _integer(r, doc["seed"], "seed", *SEED_RANGE)
    rig = _rig(r, doc["rig"])
    centres = doc["centres_mm"]
    if not isinstance(centres, list) or len(centres) != 2:
        r.fail("centres_mm", f"must be a list of two [x, y] points (got {describe(centres)})")
    centres = [r.vector(c, f"centres_mm[{i}]", 2, MAX_MM) for i, c in enumerate(centres)]
    observations = _observations(r, doc)
    stage1 = _stage(r, doc, "stage1", get_model(model).param_names)
    stage2 = _stage(r, doc, "stage2", AffinePair.param_names)
    for name in AFFINE_SCALES:
        if stage2.params[name] <= 0:
            r.fail(f"stage2.params.{name}", f"must be > 0, a scale (got {stage2.params[name]})")
    n = len(observations["depth_mm"]) if observations else None
    for key, s in (("stage1", stage1), ("stage2", stage2)):
        n = n or len(s.residuals_mm) or None
        if s.residuals_mm and len(s.residuals_mm) != n:
            r.fail(f"{key}.residuals_mm", f"must have {n} entries, one per landmark (got "
                   f"{len(s.residuals_mm)})")  # fmt: skip
    centre_index = _integer(r, doc["centre_index"], "centre_index", 0, None if n is None else n - 1)
    settings = _optional_table(r, doc, "settings")
    for key, check in {**_SETTINGS, **_LEGACY_SETTINGS}.items():
        if key in settings:
            check(r, settings[key], f"settings.{key}")
    dataset = doc.get("dataset", "")
    if not isinstance(dataset, str):
        r.fail("dataset", f"must be a string (got {describe(dataset)})")
    timings = _optional_table(r, doc, "timings_s")
    for key, value in timings.items():
        r.number(value, f"timings_s.{key}")
    warnings = doc.get("warnings", [])
    if not isinstance(warnings, list):
        r.fail("warnings", f"must be an array of strings (got {describe(warnings)})")
    for i, w in enumerate(warnings):
        if not isinstance(w, str):
            r.fail(f"warnings[{i}]", f"must be a string (got {describe(w)})")
    return CalibrationResult(
        model=model,
        seed=seed,
        settings=settings,
        dataset=dataset,
        rig=rig,
        stage1=stage1,
        stage2=stage2,
        centre_index=centre_index,
        centres_mm=centres,
        timings_s=timings,
        sign_twin=_optional_table(r, doc, "sign_twin"),
        warnings=warnings,
        diagnostics=_diagnostics(r, doc, n, (stage1, stage2)),
        observations=observations,
    )


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


def _model_name(r: Reader, x: Any, where: str) -> str:
    if not isinstance(x, str) or x not in model_registry():
        known = ", ".join(sorted(model_registry()))
        r.fail(where, f"unknown model {describe(x)}; known: {known}")
    return x


def _loss_name(r: Reader, x: Any, where: str) -> str:
    if not isinstance(x, str) or x not in LOSS_NAMES:
        r.fail(where, f"unknown loss {describe(x)}; known: {', '.join(LOSS_NAMES)}")
    return x


#: Checks of the calibration settings a result records (handeye_jax.calibrate.Settings);
#: the evaluation refits stage 2 with them.
_SETTINGS: dict[str, Callable[[Reader, Any, str], Any]] = {
    "model": _model_name,
    "seed": lambda r, x, w: _integer(r, x, w, *SEED_RANGE),
    "population": lambda r, x, w: _integer(r, x, w, 4, MAX_POPULATION),
    "generations": lambda r, x, w: _integer(r, x, w, 1, MAX_GENERATIONS),
    "early_stop": _boolean,
    "tol": lambda r, x, w: r.number(x, w),
    "crossover": lambda r, x, w: r.number(x, w),
    "mutation": lambda r, x, w: r.number(x, w),
    "polish": _boolean,
    "restarts": lambda r, x, w: _integer(r, x, w, 0, MAX_RESTARTS),
    "loss": _loss_name,
    "loss_scale_mm": lambda r, x, w: r.number(x, w, positive=True),
}
#: Settings older results recorded and the fit no longer has (checked, then ignored).
_LEGACY_SETTINGS = {"diagnostics": _boolean}
#: Checks of the DE and LM summaries of a stage, by key; other keys are kept unchecked.
_DE = {"F": Reader.number, "generations": _count, "evaluations": _count, "converged": _boolean}
_POLISH = {
    "ran": _boolean, "accepted": _boolean, "F_before": Reader.number, "F_after": Reader.number,
    "steps": _count, "solver_converged": _boolean,
}  # fmt: skip


def _rig(r: Reader, value: Any) -> dict[str, Any]:
    rig = r.table(value, "rig", ("camera_px", "capture_hand_position_mm", "hand_angle"))
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
    return StageResult(
        F=F, f1=f1, f2=f2, params=params, residuals_mm=residuals, de=de, polish=polish,
        convergence=_convergence(r, s, key),
    )  # fmt: skip


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


def _optional_table(r: Reader, doc: dict[str, Any], key: str) -> dict[str, Any]:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        r.fail(key, f"must be an object (got {describe(value)})")
    return value


def _observations(r: Reader, doc: dict[str, Any]) -> dict[str, Any]:
    """The optional ``observations`` section, checked for shapes and finite numbers."""
    obs = _optional_table(r, doc, "observations")
    if not obs:
        return {}
    r.table(obs, "observations", (*OBSERVATION_ARRAYS, "mm_per_tablet_px"))
    lo, hi = MM_PER_TABLET_PX
    r.number(obs["mm_per_tablet_px"], "observations.mm_per_tablet_px", positive=True,
             limit=hi, minimum=lo, unit="mm")  # fmt: skip
    n = None
    for name, tail in OBSERVATION_ARRAYS.items():
        where = f"observations.{name}"
        rows = obs[name]
        if not isinstance(rows, list) or not rows or (n is not None and len(rows) != n):
            want = "a non-empty list" if n is None else f"a list of {n} (one per landmark)"
            r.fail(where, f"must be {want} (got {describe(rows)})")
        if len(rows) > MAX_LANDMARKS:
            r.fail(where, f"has {len(rows):,} landmarks; at most {MAX_LANDMARKS:,}")
        n = len(rows)
        limit = OBSERVATION_LIMITS[name]
        for i, row in enumerate(rows):
            if tail:
                r.vector(row, f"{where}[{i}]", tail[0], limit)
            else:
                r.number(row, f"{where}[{i}]", positive=name == "depth_mm", limit=limit)
    return obs


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
