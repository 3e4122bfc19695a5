"""The robot's side, NumPy only (no JAX): the fitted frames as plain numbers
(:class:`Frames`), a result file's parts checked against each other and the rig's reach, the
hand command from them (:class:`Predictor`), and their exports (URDF, ROS 2, OpenCV, YAML,
JSON, a NumPy module). A robot PC needs nothing above this folder."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_export": (
        "carried_stage", "check_parses", "EASY_HANDEYE_PARAMETERS", "export_text",
        "quaternion_xyzw", "RIGID_ONLY_FORMATS", "StageError", "zero_filled",
    ),
    "_frames": ("Affine", "Frames", "TRANSLATIONS"),
    "_names": (
        "DEFAULT_BASE_FRAME", "DEFAULT_CAMERA_FRAME", "DEFAULT_PARENT_LINK", "DEFAULT_PEN_FRAME",
        "FORMATS", "FrameNames", "NAME_PATTERN",
    ),
    "_heights": ("filled_translations_mm", "with_heights"),
    "_predictor": ("Predictor", "read_json", "result_reach", "stored_frames", "stored_result"),
    "_trust": ("check_reach", "check_result_document"),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
