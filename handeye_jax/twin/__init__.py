"""A synthetic twin of the rig with known truth: draw or change a truth (near the paper's
rig, or a random wide rig anywhere in the workspace), synthesize the observations, render the
pictures, simulate a twin folder, evaluate a calibration on its held-out targets, and plan an
acquisition: its expected error before it is taken (linearised or Monte Carlo) and its layout
optimised by gradient."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_evaluate": (
        "evaluate", "evaluate_points", "evaluate_twin", "format_evaluation", "Heldout",
        "load_heldout", "PointErrors", "TouchingError",
    ),
    "_plan": (
        "Acquisition", "AcquisitionError", "default_workspace", "errors_on_workspace",
        "exact_dataset", "grid_acquisition", "layout_acquisition", "LayoutSearch",
        "monte_carlo_acquisition", "noisy_dataset", "optimise_layout", "OptimisedLayout",
        "planning_truth", "predict_acquisition", "recommend", "StageError", "summarise",
        "Workspace", "workspace_as_targets", "workspace_heldout",
    ),
    "_render": ("render_capture", "render_depth"),
    "_simulate": (
        "check_twin_folder", "encode_png", "heldout_targets", "HeldoutLevels", "NoisePreset",
        "PRESETS", "simulate", "Twin", "write_twin",
    ),
    "_synthetic": ("Scene", "seen_from", "synthesize_dataset", "true_command"),
    "_poses": ("tool_poses",),
    "_truth": ("change_truth", "draw_truth", "load_truth", "REALSENSE_LIKE", "TwinTruth"),
    "_wide": ("aimed_position", "draw_wide_truth", "upright_angle", "WIDE_DOT_PX", "WIDE_RANGES"),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
