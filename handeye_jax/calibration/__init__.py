"""The fit: settings, where each stage searches (a box around a closed-form estimate of the
rig, or the paper's ranges), plans (what each stage fits), one stage's search for its best
optimum (DE, LM polish, restarts, multi-start refits; the lowest wins), the two-stage
pipelines (calibrate, recalibrate, with a prior's rig checked against the new data), the
warnings with what would help, and the result with its file. The only place that joins the
hand–eye problem to the optimisers."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_advice": ("AdviceContext", "bound_hits", "bound_warning"),
    "_batch": ("calibrate_batch", "fit_batch", "WAVE"),
    "_fitted": ("fitted_stages", "FittedStage"),
    "_payloads": (
        "Ambiguity", "Bootstrap", "BoundHit", "Convention", "ConventionCheck", "ConventionFit",
        "Convergence", "Deployment", "DESummary", "Diagnostics", "ErrorMap", "ExpectedError",
        "FitWarning", "HeldOut", "LeaveOneOut", "LossInfo", "Mode", "Mount", "NO_EVIDENCE",
        "PolishSummary", "Pose", "PriorReport", "Pull", "Recalibration", "Residual", "Scope",
        "SignTwin", "StageDiagnostics",
    ),
    "_likelihood": (
        "is_ml", "ml_objective", "noise_part", "polish", "prior_information", "refine_ml",
    ),
    "_pipeline": ("calibrate", "fit", "fit_correction", "recalibrate", "recalibrate_batch"),
    "_plans": ("full_plan", "Plan", "recalibration_plan"),
    "_result": ("CalibrationResult", "StageResult"),
    "_result_frames": ("compute_frames",),
    "_ranges": (
        "BOX_SIGMAS", "estimate_box", "HALF_WIDTH", "plan_search", "SearchPlan", "SearchRange",
        "SearchReport",
    ),
    "_result_io": (
        "load_frames", "load_result", "result_from_json", "result_to_json", "save_result",
    ),
    "_rig_change": ("change_line",),
    "_settings": ("Settings",),
    "_search": ("fit_stage", "fit_stages"),
    "_stage": ("POLISH", "Population", "StageFit", "with_prior"),
    "_tasks": ("EXACT_ROWS", "padded_rows", "RESTART_LANDMARKS"),
    "_starts": ("convention_index", "CONVENTIONS", "REFIT_STARTS", "uniform_starts"),
    "_warnings": ("all_warnings", "check_determined", "PULL_FLAG"),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
