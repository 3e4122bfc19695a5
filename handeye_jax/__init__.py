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
    "AbstractBlock": "problem._objective",
    "AbstractCorrection": "models",
    "AbstractLoss": "problem._losses",
    "AbstractModel": "models",
    "AbstractObjective": "problem._objective",
    "AffinePair": "models",
    "analyse_jacobian": "problem._linearise",
    "calibrate": "calibration._calibrate",
    "CalibrationResult": "calibration._result",
    "Camera": "data._dataset",
    "change_truth": "twin._truth",
    "Capture": "data._dataset",
    "capture_scope": "diagnostics._scope",
    "CauchyLoss": "problem._losses",
    "chain_points": "problem._objective",
    "ChainPoints": "problem._objective",
    "compute_frames": "calibration._result_frames",
    "convert_to_v2": "data._dataset_io",
    "Dataset": "data._dataset",
    "dataset_to_toml": "data._dataset_io",
    "detect_landmarks": "vision._detect",
    "Detection": "vision._detect",
    "DetectSettings": "vision._detect",
    "DHModel": "models",
    "diagnose": "calibration._calibrate",
    "draw_truth": "twin._truth",
    "errors_of": "problem._objective",
    "evaluate": "twin._evaluate",
    "evaluate_points": "twin._evaluate",
    "evaluate_twin": "twin._evaluate",
    "export_text": "robot._export",
    "fill_capture": "vision._detect",
    "fill_dataset": "vision._detect",
    "fit": "calibration._calibrate",
    "fit_correction": "calibration._calibrate",
    "fit_stage": "calibration._calibrate",
    "fitness": "problem._objective",
    "float64": "_jax._x64",
    "format_evaluation": "twin._evaluate",
    "format_summary": "report._summary",
    "Frames": "robot._frames",
    "GaussianBlock": "problem._objective",
    "GaussianObjective": "problem._objective",
    "full_plan": "calibration._calibrate",
    "get_loss": "problem._losses",
    "get_model": "models",
    "Heldout": "twin._evaluate",
    "hand_command": "data._points",
    "HeightOffsets": "problem._objective",
    "HTMModel": "models",
    "HuberLoss": "problem._losses",
    "InputError": "_core._errors",
    "jacobian_diagnostics": "problem._linearise",
    "L1Loss": "problem._losses",
    "LengthBlock": "problem._objective",
    "load_dataset": "data._dataset_io",
    "load_frames": "calibration._result_frames",
    "load_heldout": "twin._evaluate",
    "load_result": "calibration._result_io",
    "load_truth": "twin._truth",
    "LossObjective": "problem._objective",
    "NoisePreset": "twin._simulate",
    "Observations": "data._observations",
    "ParameterSpace": "problem._params",
    "Plan": "calibration._calibrate",
    "PointErrors": "twin._evaluate",
    "Predictor": "robot._predictor",
    "PRESETS": "twin._simulate",
    "Prior": "problem._params",
    "plan_captures": "vision._captures",
    "PriorObjective": "problem._objective",
    "put": "problem._params",
    "recalibrate": "calibration._calibrate",
    "recalibration_plan": "calibration._calibrate",
    "render": "report._figures",
    "resolve_names": "problem._params",
    "Rig": "data._observations",
    "save_dataset": "data._dataset_io",
    "save_result": "calibration._result_io",
    "Settings": "calibration._settings",
    "simulate": "twin._simulate",
    "simulate_captures": "twin._simulate",
    "snake_grid_px": "twin._synthetic",
    "SquaresBlock": "problem._objective",
    "Stage1Objective": "problem._objective",
    "Stage2Objective": "problem._objective",
    "StageErrors": "problem._objective",
    "StageFit": "calibration._calibrate",
    "StageResult": "calibration._result",
    "synthesize_captures": "twin._synthetic",
    "store_programs": "_jax._xla",
    "synthesize_dataset": "twin._synthetic",
    "TouchingError": "twin._evaluate",
    "Twin": "twin._simulate",
    "TwinTruth": "twin._truth",
    "update_dataset": "data._dataset_io",
    "vectorise_small_loops": "_jax._xla",
    "WeightedLengthBlock": "problem._objective",
    "write_report": "report._figures",
    "write_twin": "twin._simulate",
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
    from ._core._errors import InputError
    from ._jax._x64 import float64
    from ._jax._xla import store_programs, vectorise_small_loops
    from .calibration._calibrate import (
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
    from .calibration._result import CalibrationResult, StageResult
    from .calibration._result_frames import compute_frames, load_frames
    from .calibration._result_io import load_result, save_result
    from .calibration._settings import Settings
    from .data._dataset import Camera, Capture, Dataset
    from .data._dataset_io import (
        convert_to_v2,
        dataset_to_toml,
        load_dataset,
        save_dataset,
        update_dataset,
    )
    from .data._observations import Observations, Rig
    from .data._points import hand_command
    from .diagnostics._scope import capture_scope
    from .models import AbstractCorrection, AbstractModel, AffinePair, DHModel, HTMModel, get_model
    from .problem._linearise import analyse_jacobian, jacobian_diagnostics
    from .problem._losses import AbstractLoss, CauchyLoss, HuberLoss, L1Loss, get_loss
    from .problem._objective import (
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
    from .problem._params import ParameterSpace, Prior, put, resolve_names
    from .report._figures import render, write_report
    from .report._summary import format_summary
    from .robot._export import export_text
    from .robot._frames import Frames
    from .robot._predictor import Predictor
    from .twin._evaluate import (
        Heldout,
        PointErrors,
        TouchingError,
        evaluate,
        evaluate_points,
        evaluate_twin,
        format_evaluation,
        load_heldout,
    )
    from .twin._simulate import PRESETS, NoisePreset, Twin, simulate, simulate_captures, write_twin
    from .twin._synthetic import snake_grid_px, synthesize_captures, synthesize_dataset
    from .twin._truth import TwinTruth, change_truth, draw_truth, load_truth
    from .vision._captures import plan_captures
    from .vision._detect import (
        Detection,
        DetectSettings,
        detect_landmarks,
        fill_capture,
        fill_dataset,
    )

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
