"""The fit: settings, plans (what each stage fits), one stage's search for its best optimum
(DE, LM polish, restarts, multi-start refits; the lowest wins), the two-stage pipelines
(calibrate, recalibrate), the warnings, and the result with its file. The only place that
joins the hand–eye problem to the optimisers."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_calibrate": (
        "all_warnings", "bound_hits", "calibrate", "convention_index", "CONVENTIONS", "fit",
        "fit_correction", "fit_stage", "fitted_stages", "FittedStage", "full_plan", "Plan",
        "POLISH", "Population", "PULL_FLAG", "recalibrate", "recalibration_plan", "REFIT_STARTS",
        "StageFit", "uniform_starts",
    ),
    "_payloads": (
        "Convention", "ConventionCheck", "ConventionFit", "Convergence", "DESummary", "Diagnostics",
        "FitWarning", "HeldOut", "LeaveOneOut", "LossInfo", "Mode", "PolishSummary", "PriorReport",
        "Pull", "Recalibration", "Residual", "Scope", "SignTwin", "StageDiagnostics",
    ),
    "_result": ("CalibrationResult", "StageResult"),
    "_result_frames": ("compute_frames",),
    "_result_io": ("load_frames", "load_result", "result_to_json", "save_result"),
    "_settings": ("Settings",),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
