"""The fit: settings, plans (what each stage fits), one stage's search for its best optimum
(DE, LM polish, restarts, multi-start refits; the lowest wins), the two-stage pipelines
(calibrate, recalibrate), the warnings, and the result with its file. The only place that
joins the hand–eye problem to the optimisers."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
_EXPORTS = {
    "_calibrate": (
        "calibrate",
        "diagnose",
        "fit",
        "fit_correction",
        "fit_stage",
        "full_plan",
        "Plan",
        "recalibrate",
        "recalibration_plan",
        "StageFit",
    ),
    "_result": ("CalibrationResult", "StageResult"),
    "_result_frames": ("compute_frames",),
    "_result_io": ("load_frames", "load_result", "result_to_json", "save_result"),
    "_settings": ("Settings",),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
