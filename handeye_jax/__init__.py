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
from typing import TYPE_CHECKING

from ._core import package_version

_SUBMODULES = ("geometry", "models", "optim", "tablet")
_EXPORTS = {
    "ConventionCheck": "calibration",
    "Convergence": "calibration",
    "DESummary": "calibration",
    "Diagnostics": "calibration",
    "FitWarning": "calibration",
    "LeaveOneOut": "calibration",
    "Mode": "calibration",
    "PolishSummary": "calibration",
    "PriorReport": "calibration",
    "Pull": "calibration",
    "Recalibration": "calibration",
    "Residual": "calibration",
    "Scope": "calibration",
    "SignTwin": "calibration",
    "StageDiagnostics": "calibration",
    "Heights": "problem",
    "JacobianAnalysis": "problem",
    "WeakDirection": "problem",
    "AbstractBlock": "problem",
    "AbstractCorrection": "models",
    "AbstractLoss": "problem",
    "AbstractModel": "models",
    "AbstractObjective": "problem",
    "AffinePair": "models",
    "analyse_jacobian": "problem",
    "calibrate": "calibration",
    "calibrate_batch": "calibration",
    "CalibrationResult": "calibration",
    "Camera": "data",
    "change_truth": "twin",
    "Capture": "data",
    "capture_scope": "diagnostics",
    "CauchyLoss": "problem",
    "chain_points": "problem",
    "ChainPoints": "problem",
    "compute_frames": "calibration",
    "convert_to_v2": "data",
    "Dataset": "data",
    "dataset_to_toml": "data",
    "detect_landmarks": "vision",
    "Detection": "vision",
    "DetectSettings": "vision",
    "DHModel": "models",
    "diagnose": "diagnostics",
    "draw_truth": "twin",
    "Acquisition": "twin",
    "AcquisitionError": "twin",
    "grid_acquisition": "twin",
    "monte_carlo_acquisition": "twin",
    "LayoutSearch": "twin",
    "optimise_layout": "twin",
    "planning_truth": "twin",
    "predict_acquisition": "twin",
    "recommend": "twin",
    "errors_of": "problem",
    "evaluate": "twin",
    "evaluate_points": "twin",
    "evaluate_twin": "twin",
    "export_text": "robot",
    "FrameNames": "robot",
    "fill_capture": "vision",
    "fill_dataset": "vision",
    "fit": "calibration",
    "fit_correction": "calibration",
    "fit_stage": "calibration",
    "fitness": "problem",
    "float64": "_jax",
    "format_evaluation": "twin",
    "format_summary": "report",
    "Frames": "robot",
    "GaussianBlock": "problem",
    "GaussianObjective": "problem",
    "full_plan": "calibration",
    "get_loss": "problem",
    "get_model": "models",
    "Heldout": "twin",
    "hand_command": "models",
    "HeightOffsets": "problem",
    "HTMModel": "models",
    "HuberLoss": "problem",
    "InputError": "_core",
    "jacobian_diagnostics": "problem",
    "L1Loss": "problem",
    "LengthBlock": "problem",
    "load_dataset": "data",
    "load_frames": "calibration",
    "load_heldout": "twin",
    "load_result": "calibration",
    "load_truth": "twin",
    "LossObjective": "problem",
    "NoisePreset": "twin",
    "Observations": "data",
    "ParameterSpace": "problem",
    "Plan": "calibration",
    "PointErrors": "twin",
    "Predictor": "robot",
    "PRESETS": "twin",
    "Prior": "problem",
    "plan_captures": "vision",
    "planned_view": "vision",
    "PlannedView": "vision",
    "PriorObjective": "problem",
    "problem_mesh": "_jax",
    "put": "problem",
    "recalibrate": "calibration",
    "recalibrate_batch": "calibration",
    "recalibration_plan": "calibration",
    "render": "report",
    "resolve_names": "problem",
    "Rig": "models",
    "save_dataset": "data",
    "save_result": "calibration",
    "Settings": "calibration",
    "simulate": "twin",
    "snake_grid_px": "data",
    "SquaresBlock": "problem",
    "Stage1Objective": "problem",
    "Stage2Objective": "problem",
    "StageErrors": "problem",
    "StageFit": "calibration",
    "StageResult": "calibration",
    "Scene": "twin",
    "store_programs": "_jax",
    "synthesize_dataset": "twin",
    "Targets": "models",
    "TouchingError": "twin",
    "Twin": "twin",
    "TwinTruth": "twin",
    "update_dataset": "data",
    "vectorise_small_loops": "_jax",
    "WeightedLengthBlock": "problem",
    "write_report": "report",
    "write_twin": "twin",
    "closed_form_estimate": "problem",
    "ClosedFormEstimate": "problem",
    "RigEstimate": "problem",
    "moved_base": "data",
    "draw_wide_truth": "twin",
    "WIDE_RANGES": "twin",
    "SearchReport": "calibration",
    "SearchRange": "calibration",
    "plan_search": "calibration",
    "apply_poses": "data",
    "PoseReport": "data",
    "read_intrinsics": "data",
    "read_poses_csv": "data",
    "ToolPose": "data",
    "tool_pose_of_hand": "data",
    "undistort_px": "data",
    "distort_px": "data",
    "with_heights": "robot",
    "tool_poses": "twin",
    "REALSENSE_LIKE": "twin",
    "bootstrap": "diagnostics",
    "Bootstrap": "calibration",
    "ErrorMap": "calibration",
}
# What a robot PC may lack; Predictor and Frames need none of it.
_JAX_STACK = ("jax", "jaxlib", "equinox", "optimistix", "jaxtyping", "lineax", "jaxlie")


def __getattr__(name: str):
    if name == "__version__":  # read when asked: the installed metadata's reader cost every
        # command's start about a fifth (benchmarks/RESULTS.md)
        globals()[name] = value = package_version()
        return value
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    try:
        value = getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    except ImportError as e:
        if (e.name or "").split(".")[0] not in _JAX_STACK:
            raise
        raise ImportError(
            f"handeye_jax.{name} needs JAX, which cannot be imported here ({e}); Predictor "
            "and Frames work without it"
        ) from e
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_SUBMODULES, *_EXPORTS})


if TYPE_CHECKING:
    from . import geometry, models, optim, tablet
    from ._core._errors import InputError
    from ._jax._shard import problem_mesh
    from ._jax._x64 import float64
    from ._jax._xla import store_programs, vectorise_small_loops
    from .calibration._batch import calibrate_batch
    from .calibration._payloads import (
        Bootstrap,
        ConventionCheck,
        Convergence,
        DESummary,
        Diagnostics,
        ErrorMap,
        FitWarning,
        LeaveOneOut,
        Mode,
        PolishSummary,
        PriorReport,
        Pull,
        Recalibration,
        Residual,
        Scope,
        SignTwin,
        StageDiagnostics,
    )
    from .calibration._pipeline import (
        calibrate,
        fit,
        fit_correction,
        recalibrate,
        recalibrate_batch,
    )
    from .calibration._plans import Plan, full_plan, recalibration_plan
    from .calibration._ranges import SearchRange, SearchReport, plan_search
    from .calibration._result import CalibrationResult, StageResult
    from .calibration._result_frames import compute_frames
    from .calibration._result_io import load_frames, load_result, save_result
    from .calibration._search import fit_stage
    from .calibration._settings import Settings
    from .calibration._stage import StageFit
    from .data._convert import convert_to_v2
    from .data._dataset import Camera, Capture, Dataset
    from .data._edit import update_dataset
    from .data._hand_poses import PoseReport, apply_poses
    from .data._intrinsics import read_intrinsics
    from .data._layouts import snake_grid_px
    from .data._lens import distort_px, undistort_px
    from .data._moved import moved_base
    from .data._observations import Observations
    from .data._poses import ToolPose, read_poses_csv, tool_pose_of_hand
    from .data._read import load_dataset
    from .data._write import dataset_to_toml, save_dataset
    from .diagnostics._bootstrap import bootstrap
    from .diagnostics._diagnose import diagnose
    from .diagnostics._scope import capture_scope
    from .models import (
        AbstractCorrection,
        AbstractModel,
        AffinePair,
        DHModel,
        HTMModel,
        Rig,
        Targets,
        get_model,
        hand_command,
    )
    from .problem._estimate import ClosedFormEstimate, RigEstimate, closed_form_estimate
    from .problem._linearise import (
        JacobianAnalysis,
        WeakDirection,
        analyse_jacobian,
        jacobian_diagnostics,
    )
    from .problem._losses import AbstractLoss, CauchyLoss, HuberLoss, L1Loss, get_loss
    from .problem._objective import (
        AbstractBlock,
        AbstractObjective,
        ChainPoints,
        GaussianBlock,
        GaussianObjective,
        HeightOffsets,
        Heights,
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
    from .robot._heights import with_heights
    from .robot._names import FrameNames
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
    from .twin._plan import (
        Acquisition,
        AcquisitionError,
        LayoutSearch,
        grid_acquisition,
        monte_carlo_acquisition,
        optimise_layout,
        planning_truth,
        predict_acquisition,
        recommend,
    )
    from .twin._poses import tool_poses
    from .twin._simulate import PRESETS, NoisePreset, Twin, simulate, write_twin
    from .twin._synthetic import Scene, synthesize_dataset
    from .twin._truth import REALSENSE_LIKE, TwinTruth, change_truth, draw_truth, load_truth
    from .twin._wide import WIDE_RANGES, draw_wide_truth
    from .vision._captures import PlannedView, plan_captures, planned_view
    from .vision._detect import (
        Detection,
        DetectSettings,
        detect_landmarks,
        fill_capture,
        fill_dataset,
    )

__all__ = [
    "ConventionCheck",
    "Convergence",
    "DESummary",
    "Diagnostics",
    "FitWarning",
    "LeaveOneOut",
    "Mode",
    "PolishSummary",
    "PriorReport",
    "Pull",
    "Recalibration",
    "Residual",
    "Scope",
    "SignTwin",
    "StageDiagnostics",
    "Heights",
    "JacobianAnalysis",
    "WeakDirection",
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
    "Targets",
    "TouchingError",
    "Twin",
    "TwinTruth",
    "WeightedLengthBlock",
    "analyse_jacobian",
    "calibrate",
    "calibrate_batch",
    "chain_points",
    "change_truth",
    "compute_frames",
    "convert_to_v2",
    "dataset_to_toml",
    "detect_landmarks",
    "diagnose",
    "draw_truth",
    "Acquisition",
    "AcquisitionError",
    "grid_acquisition",
    "monte_carlo_acquisition",
    "LayoutSearch",
    "optimise_layout",
    "planning_truth",
    "predict_acquisition",
    "recommend",
    "errors_of",
    "evaluate",
    "evaluate_twin",
    "export_text",
    "FrameNames",
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
    "problem_mesh",
    "put",
    "recalibrate",
    "recalibrate_batch",
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
    "Scene",
    "closed_form_estimate",
    "ClosedFormEstimate",
    "RigEstimate",
    "moved_base",
    "draw_wide_truth",
    "WIDE_RANGES",
    "SearchReport",
    "SearchRange",
    "plan_search",
    "apply_poses",
    "PoseReport",
    "read_intrinsics",
    "read_poses_csv",
    "ToolPose",
    "tool_pose_of_hand",
    "undistort_px",
    "distort_px",
    "with_heights",
    "tool_poses",
    "REALSENSE_LIKE",
    "bootstrap",
    "Bootstrap",
    "ErrorMap",
]
