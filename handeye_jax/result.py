"""The calibration result and its file format, ``handeye-jax.result/1`` (JSON).

A result is self-contained: with the rig it was fitted on (intrinsics, capture pose, hand-angle
convention) it predicts hand commands without the dataset.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._atomic import write_text_atomic
from ._validate import _describe, _Reader
from ._x64 import in_float64
from .errors import InputError
from .models import AbstractCorrection, AbstractModel, AffinePair, get_model, model_registry
from .observations import Rig
from .predict import hand_command

if TYPE_CHECKING:
    from .dataset import Dataset

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
    format: str = FORMAT

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

    # -- files ---------------------------------------------------------------------------
    def to_json(self) -> str:
        def stage(s: StageResult) -> dict[str, Any]:
            return {
                "F": s.F, "f1": s.f1, "f2": s.f2, "params": s.params,
                "residuals_mm": s.residuals_mm, "de": s.de, "polish": s.polish,
                "convergence": s.convergence,
            }  # fmt: skip

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
        }
        # Optional sections (older results lack them): see handeye_jax.diagnostics.
        if self.diagnostics:
            doc["diagnostics"] = self.diagnostics
        if self.observations:
            doc["observations"] = self.observations
        return json.dumps(doc, indent=2, allow_nan=False) + "\n"

    def save(self, path: str | Path) -> None:
        """Write the result atomically: the file is complete or not written at all."""
        write_text_atomic(path, self.to_json())


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


def rig_from_dict(d: dict[str, Any]) -> Rig:
    cam = d["camera_px"]
    return Rig(
        cam["fx"], cam["fy"], cam["cx"], cam["cy"],
        d["capture_hand_position_mm"], d["hand_angle"]["zero_deg"], d["hand_angle"]["sign"],
    )  # fmt: skip


# -- loading with validation ---------------------------------------------------------------


def load_result(path: str | Path) -> CalibrationResult:
    """Read and validate a ``handeye-jax.result/1`` file; raises :class:`InputError`."""
    path = Path(path)
    r = _Reader(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(path, "", f"cannot read file: {e}") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(path, "", f"not valid JSON: {e}") from None
    if not isinstance(doc, dict):
        r.fail("", "must be a JSON object")
    if doc.get("format") != FORMAT:
        r.fail("format", f"expected {FORMAT!r} (got {_describe(doc.get('format'))})")
    model = doc.get("model")
    if model not in model_registry():
        known = ", ".join(sorted(model_registry()))
        r.fail("model", f"unknown model {_describe(model)}; known: {known}")
    rig = r.table(doc.get("rig"), "rig", ("camera_px", "capture_hand_position_mm", "hand_angle"))
    cam = r.table(rig["camera_px"], "rig.camera_px", ("fx", "fy", "cx", "cy"))
    for k in ("fx", "fy"):
        r.number(cam[k], f"rig.camera_px.{k}", positive=True)
    for k in ("cx", "cy"):
        r.number(cam[k], f"rig.camera_px.{k}")
    r.vector(rig["capture_hand_position_mm"], "rig.capture_hand_position_mm", 3)
    angle = r.table(rig["hand_angle"], "rig.hand_angle", ("zero_deg", "sign"))
    r.number(angle["zero_deg"], "rig.hand_angle.zero_deg")
    if r.number(angle["sign"], "rig.hand_angle.sign") not in (1.0, -1.0):
        r.fail("rig.hand_angle.sign", f"must be 1 or -1 (got {angle['sign']})")
    centres = doc.get("centres_mm")
    if not isinstance(centres, list) or len(centres) != 2:
        r.fail("centres_mm", f"must be a list of two [x, y] points (got {_describe(centres)})")
    centres = [r.vector(c, f"centres_mm[{i}]", 2) for i, c in enumerate(centres)]

    def stage(key: str, names: tuple[str, ...]) -> StageResult:
        s = doc.get(key)
        if not isinstance(s, dict):
            r.fail(key, f"must be an object (got {_describe(s)})")
        F, f1, f2 = (r.number(s.get(k), f"{key}.{k}") for k in ("F", "f1", "f2"))
        p = r.table(s.get("params"), f"{key}.params", names)
        params = {n: r.number(p[n], f"{key}.params.{n}") for n in names}
        return StageResult(
            F=F, f1=f1, f2=f2, params=params,
            residuals_mm=s.get("residuals_mm", []), de=s.get("de", {}),
            polish=s.get("polish", {}), convergence=s.get("convergence", {}),
        )  # fmt: skip

    seed = doc.get("seed")
    if isinstance(seed, bool) or not isinstance(seed, int):
        r.fail("seed", f"must be an integer (got {_describe(seed)})")
    return CalibrationResult(
        model=model,
        seed=seed,
        settings=doc.get("settings", {}),
        dataset=str(doc.get("dataset", "")),
        rig=rig,
        stage1=stage("stage1", get_model(model).param_names),
        stage2=stage("stage2", AffinePair.param_names),
        centre_index=int(doc.get("centre_index", 0)),
        centres_mm=centres,
        timings_s=doc.get("timings_s", {}),
        sign_twin=doc.get("sign_twin", {}),
        warnings=list(doc.get("warnings", [])),
        diagnostics=_optional_table(r, doc, "diagnostics"),
        observations=_observations(r, doc),
    )


def _optional_table(r: _Reader, doc: dict[str, Any], key: str) -> dict[str, Any]:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        r.fail(key, f"must be an object (got {_describe(value)})")
    return value


def _observations(r: _Reader, doc: dict[str, Any]) -> dict[str, Any]:
    """The optional ``observations`` section, checked for shapes and finite numbers."""
    obs = _optional_table(r, doc, "observations")
    if not obs:
        return {}
    r.table(obs, "observations", (*OBSERVATION_ARRAYS, "mm_per_tablet_px"))
    r.number(obs["mm_per_tablet_px"], "observations.mm_per_tablet_px", positive=True)
    n = None
    for name, tail in OBSERVATION_ARRAYS.items():
        where = f"observations.{name}"
        rows = obs[name]
        if not isinstance(rows, list) or not rows or (n is not None and len(rows) != n):
            want = "a non-empty list" if n is None else f"a list of {n} (one per landmark)"
            r.fail(where, f"must be {want} (got {_describe(rows)})")
        n = len(rows)
        for i, row in enumerate(rows):
            if tail:
                r.vector(row, f"{where}[{i}]", tail[0])
            else:
                r.number(row, f"{where}[{i}]")
    return obs
