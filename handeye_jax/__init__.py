"""handeye-jax: differentiable hand-eye calibration for handmade end-effectors, in JAX.

Data flows one way: a dataset file → validated arrays (:class:`Dataset`, :class:`Observations`)
→ a problem (a model template, its free parameters and an objective, :class:`ParameterSpace`,
:class:`Stage1Objective`) → solvers (:mod:`handeye_jax.optim`) → a :class:`CalibrationResult`
→ a report, predictions or an export.

Everything listed in ``__all__`` is the API; modules whose names start with ``_`` are not. The
names load on first use (PEP 562), so that ``import handeye_jax`` is quick and the NumPy-only
:class:`Predictor` and :class:`Frames` work on a robot PC without JAX.

Float64: importing this package does not change JAX's global configuration. The public entry
points (``calibrate``, ``CalibrationResult.predict``, ``load_dataset``…) compute in float64
whatever your setting; wrap your own calls of the low-level functions in
``with handeye_jax.float64():`` (or set ``JAX_ENABLE_X64=1``) to get float64 there too.
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version
from typing import TYPE_CHECKING

try:
    __version__ = version("handeye-jax")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"

_SUBMODULES = ("geometry", "models", "optim", "tablet")
_EXPORTS = {
    "AbstractBlock": "_objective",
    "AbstractCorrection": "models",
    "AbstractLoss": "_losses",
    "AbstractModel": "models",
    "AbstractObjective": "_objective",
    "AffinePair": "models",
    "analyse_jacobian": "_identifiability",
    "calibrate": "_calibrate",
    "CalibrationResult": "_result",
    "Camera": "_dataset",
    "change_truth": "_twin",
    "Capture": "_dataset",
    "capture_scope": "_scope",
    "CauchyLoss": "_losses",
    "chain_points": "_objective",
    "ChainPoints": "_objective",
    "compute_frames": "_compute_frames",
    "convert_to_v2": "_dataset_io",
    "Dataset": "_dataset",
    "dataset_to_toml": "_dataset_io",
    "detect_landmarks": "_detect",
    "Detection": "_detect",
    "DetectSettings": "_detect",
    "DHModel": "models",
    "diagnose": "_calibrate",
    "draw_truth": "_twin",
    "errors_of": "_objective",
    "evaluate": "_evaluate",
    "evaluate_points": "_evaluate",
    "evaluate_twin": "_evaluate",
    "export_text": "_export",
    "fill_capture": "_detect",
    "fill_dataset": "_detect",
    "fit": "_calibrate",
    "fit_correction": "_calibrate",
    "fit_stage": "_calibrate",
    "fitness": "_objective",
    "float64": "_x64",
    "format_evaluation": "_evaluate",
    "format_summary": "_summary",
    "Frames": "_frames",
    "GaussianBlock": "_objective",
    "GaussianObjective": "_objective",
    "full_plan": "_calibrate",
    "get_loss": "_losses",
    "get_model": "models",
    "Heldout": "_evaluate",
    "hand_command": "_predict",
    "HeightOffsets": "_objective",
    "HTMModel": "models",
    "HuberLoss": "_losses",
    "InputError": "_errors",
    "jacobian_diagnostics": "_identifiability",
    "L1Loss": "_losses",
    "LengthBlock": "_objective",
    "load_dataset": "_dataset_io",
    "load_frames": "_compute_frames",
    "load_heldout": "_evaluate",
    "load_result": "_result_io",
    "load_truth": "_twin",
    "LossObjective": "_objective",
    "NoisePreset": "_simulate",
    "Observations": "_observations",
    "ParameterSpace": "_params",
    "Plan": "_calibrate",
    "PointErrors": "_evaluate",
    "Predictor": "_predictor",
    "PRESETS": "_simulate",
    "Prior": "_params",
    "plan_captures": "_plan",
    "planned_view": "_plan",
    "PlannedView": "_plan",
    "PriorObjective": "_objective",
    "put": "_params",
    "recalibrate": "_calibrate",
    "recalibration_plan": "_calibrate",
    "render": "_report",
    "resolve_names": "_params",
    "Rig": "_observations",
    "save_dataset": "_dataset_io",
    "save_result": "_result_io",
    "Settings": "_settings",
    "simulate": "_simulate",
    "simulate_captures": "_simulate",
    "snake_grid_px": "_synthetic",
    "SquaresBlock": "_objective",
    "Stage1Objective": "_objective",
    "Stage2Objective": "_objective",
    "StageErrors": "_objective",
    "StageFit": "_calibrate",
    "StageResult": "_result",
    "synthesize_captures": "_synthetic",
    "store_programs": "_xla",
    "synthesize_dataset": "_synthetic",
    "TouchingError": "_evaluate",
    "Twin": "_simulate",
    "TwinTruth": "_twin",
    "update_dataset": "_dataset_io",
    "vectorise_small_loops": "_xla",
    "WeightedLengthBlock": "_objective",
    "write_report": "_report",
    "write_twin": "_simulate",
}
# What a robot PC may lack; Predictor and Frames need none of it.
_JAX_STACK = ("jax", "jaxlib", "equinox", "optimistix", "jaxtyping", "lineax", "jaxlie")


def __getattr__(name: str):
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    try:
        module = importlib.import_module(f"{__name__}.{_EXPORTS[name]}")
    except ImportError as e:
        if (e.name or "").split(".")[0] not in _JAX_STACK:
            raise
        raise ImportError(
            f"handeye_jax.{name} needs JAX, which cannot be imported here ({e}); Predictor "
            "and Frames work without it"
        ) from e
    value = getattr(module, name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_SUBMODULES, *_EXPORTS})


if TYPE_CHECKING:
    from . import geometry, models, optim, tablet
    from ._calibrate import (
        Plan,
        StageFit,
        calibrate,
        diagnose,
        fit,
        fit_correction,
        fit_stage,
        full_plan,
        recalibrate,
        recalibration_plan,
    )
    from ._compute_frames import compute_frames, load_frames
    from ._dataset import Camera, Capture, Dataset
    from ._dataset_io import (
        convert_to_v2,
        dataset_to_toml,
        load_dataset,
        save_dataset,
        update_dataset,
    )
    from ._detect import Detection, DetectSettings, detect_landmarks, fill_capture, fill_dataset
    from ._errors import InputError
    from ._evaluate import (
        Heldout,
        PointErrors,
        TouchingError,
        evaluate,
        evaluate_points,
        evaluate_twin,
        format_evaluation,
        load_heldout,
    )
    from ._export import export_text
    from ._frames import Frames
    from ._identifiability import analyse_jacobian, jacobian_diagnostics
    from ._losses import AbstractLoss, CauchyLoss, HuberLoss, L1Loss, get_loss
    from ._objective import (
        AbstractBlock,
        AbstractObjective,
        ChainPoints,
        GaussianBlock,
        GaussianObjective,
        HeightOffsets,
        LengthBlock,
        LossObjective,
        PriorObjective,
        SquaresBlock,
        Stage1Objective,
        Stage2Objective,
        StageErrors,
        WeightedLengthBlock,
        chain_points,
        errors_of,
        fitness,
    )
    from ._observations import Observations, Rig
    from ._params import ParameterSpace, Prior, put, resolve_names
    from ._plan import PlannedView, plan_captures, planned_view
    from ._predict import hand_command
    from ._predictor import Predictor
    from ._report import render, write_report
    from ._result import CalibrationResult, StageResult
    from ._result_io import load_result, save_result
    from ._scope import capture_scope
    from ._settings import Settings
    from ._simulate import PRESETS, NoisePreset, Twin, simulate, simulate_captures, write_twin
    from ._summary import format_summary
    from ._synthetic import snake_grid_px, synthesize_captures, synthesize_dataset
    from ._twin import TwinTruth, change_truth, draw_truth, load_truth
    from ._x64 import float64
    from ._xla import store_programs, vectorise_small_loops
    from .models import AbstractCorrection, AbstractModel, AffinePair, DHModel, HTMModel, get_model

__all__ = [
    "AbstractBlock",
    "AbstractCorrection",
    "AbstractLoss",
    "AbstractModel",
    "AbstractObjective",
    "AffinePair",
    "CalibrationResult",
    "Camera",
    "Capture",
    "CauchyLoss",
    "ChainPoints",
    "DHModel",
    "Dataset",
    "DetectSettings",
    "Detection",
    "Frames",
    "GaussianBlock",
    "GaussianObjective",
    "HTMModel",
    "Heldout",
    "HuberLoss",
    "InputError",
    "L1Loss",
    "LengthBlock",
    "LossObjective",
    "NoisePreset",
    "Observations",
    "PRESETS",
    "ParameterSpace",
    "Plan",
    "PlannedView",
    "Predictor",
    "Prior",
    "PriorObjective",
    "Rig",
    "Settings",
    "SquaresBlock",
    "Stage1Objective",
    "Stage2Objective",
    "StageErrors",
    "StageFit",
    "StageResult",
    "TouchingError",
    "Twin",
    "TwinTruth",
    "WeightedLengthBlock",
    "analyse_jacobian",
    "calibrate",
    "chain_points",
    "change_truth",
    "compute_frames",
    "convert_to_v2",
    "dataset_to_toml",
    "detect_landmarks",
    "diagnose",
    "draw_truth",
    "errors_of",
    "evaluate",
    "evaluate_twin",
    "export_text",
    "fill_capture",
    "fill_dataset",
    "fit",
    "fit_correction",
    "fit_stage",
    "fitness",
    "float64",
    "format_evaluation",
    "format_summary",
    "full_plan",
    "geometry",
    "get_loss",
    "get_model",
    "hand_command",
    "jacobian_diagnostics",
    "load_dataset",
    "load_frames",
    "load_heldout",
    "load_result",
    "load_truth",
    "models",
    "optim",
    "plan_captures",
    "planned_view",
    "put",
    "recalibrate",
    "recalibration_plan",
    "render",
    "resolve_names",
    "save_dataset",
    "save_result",
    "simulate",
    "snake_grid_px",
    "store_programs",
    "synthesize_dataset",
    "tablet",
    "update_dataset",
    "vectorise_small_loops",
    "write_report",
    "write_twin",
    "capture_scope",
    "evaluate_points",
    "HeightOffsets",
    "PointErrors",
    "simulate_captures",
    "synthesize_captures",
]
