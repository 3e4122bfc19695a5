"""The fit: settings, plans (what each stage fits), one stage's search for its best optimum
(DE, LM polish, restarts, multi-start refits; the lowest wins), the two-stage pipelines
(calibrate, recalibrate, with a prior's rig checked against the new data), the warnings, and
the result with its file. The only place that
joins the hand–eye problem to the optimisers."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_fitted": ("fitted_stages", "FittedStage"),
    "_payloads": (
        "Ambiguity", "Convention", "ConventionCheck", "ConventionFit", "Convergence", "Deployment",
        "DESummary", "Diagnostics", "ExpectedError", "FitWarning", "HeldOut", "LeaveOneOut",
        "LossInfo", "Mode", "Mount", "NO_EVIDENCE", "PolishSummary", "Pose", "PriorReport", "Pull",
        "Recalibration", "Residual", "Scope", "SignTwin", "StageDiagnostics",
    ),
    "_likelihood": (
        "is_ml", "ml_objective", "noise_part", "polish", "prior_information", "refine_ml",
    ),
    "_pipeline": ("calibrate", "fit", "fit_correction", "recalibrate", "RESTART_LANDMARKS"),
    "_plans": ("full_plan", "Plan", "recalibration_plan"),
    "_result": ("CalibrationResult", "StageResult"),
    "_result_frames": ("compute_frames",),
    "_result_io": ("load_frames", "load_result", "result_to_json", "save_result"),
    "_rig_change": ("change_line",),
    "_settings": ("Settings",),
    "_stage": ("fit_stage", "POLISH", "Population", "StageFit", "with_prior"),
    "_starts": ("convention_index", "CONVENTIONS", "REFIT_STARTS", "uniform_starts"),
    "_warnings": ("all_warnings", "bound_hits", "check_determined", "PULL_FLAG"),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
