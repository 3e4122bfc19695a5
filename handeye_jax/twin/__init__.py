"""A synthetic twin of the rig with known truth: draw or change a truth, synthesize the
observations, render the pictures, simulate a twin folder, and evaluate a calibration on its
held-out targets."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_evaluate": (
        "evaluate", "evaluate_points", "evaluate_twin", "format_evaluation", "Heldout",
        "load_heldout", "PointErrors", "TouchingError",
    ),
    "_render": ("render_capture", "render_depth"),
    "_simulate": (
        "check_twin_folder", "encode_png", "heldout_targets", "NoisePreset", "PRESETS", "simulate",
        "simulate_captures", "Twin", "write_twin",
    ),
    "_synthetic": ("seen_from", "synthesize_captures", "synthesize_dataset", "true_command"),
    "_poses": ("tool_poses",),
    "_truth": ("change_truth", "draw_truth", "load_truth", "REALSENSE_LIKE", "TwinTruth"),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
