"""What a fit minimises: parameter spaces (free, fixed, with a Gaussian prior), the named
residual blocks of each stage's objective, robust losses, the linearisation at an optimum
(Jacobian, covariance, weak directions), and a closed-form first estimate of the rig from
the data alone."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_estimate": ("closed_form_estimate", "ClosedFormEstimate", "RigEstimate"),
    "_linearise": (
        "analyse_jacobian", "error_jacobian", "jacobian_diagnostics", "JacobianAnalysis",
        "NULL_RATIO", "std_of_precision", "WeakDirection",
    ),
    "_noise": (
        "estimate_noise", "get_noise_model", "NOISE_MODELS", "noise_objective", "NoiseFit",
        "NoiseModel", "NoiseObjective", "row_counts", "separated_errors", "std_dof",
        "touch_groups", "view_covariance", "whitened_jacobian",
    ),
    "_predict": (
        "command_error", "error_statistics", "ErrorPrediction", "fisher_information",
        "noise_to_parameters",
        "parameter_covariance", "predict_command_error", "StagePoint", "Targets",
        "traced_command_error", "uncertainty",
        "workspace_targets",
    ),
    "_losses": ("AbstractLoss", "CauchyLoss", "get_loss", "HuberLoss", "L1Loss", "LOSS_NAMES"),
    "_objective": (
        "AbstractBlock", "AbstractObjective", "chain_points", "ChainPoints", "data_objective",
        "errors_of", "fitness", "GaussianBlock", "GaussianObjective", "height_summary",
        "HeightOffsets", "Heights", "landmark_subset", "landmark_terms", "LengthBlock",
        "LossObjective", "norms", "PriorObjective", "spread_landmarks", "SquaresBlock",
        "stage1_errors", "Stage1Objective", "stage2_errors", "Stage2Objective", "StageErrors",
        "WeightedLengthBlock",
    ),
    "_padded": ("MaskedLengthBlock", "MaskedObjective", "pad_rows"),
    "_params": ("FIXED", "FREE", "ParameterSpace", "Prior", "put", "resolve_names"),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
