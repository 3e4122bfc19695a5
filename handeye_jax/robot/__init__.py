"""The robot's side, NumPy only (no JAX): the fitted frames as plain numbers
(:class:`Frames`), the hand command from them (:class:`Predictor`), and their exports (URDF,
ROS 2, OpenCV, YAML, JSON, a NumPy module). A robot PC needs nothing above this folder."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_export": (
        "carried_stage", "check_parses", "DEFAULT_CAMERA_FRAME", "DEFAULT_PARENT_LINK",
        "DEFAULT_PEN_FRAME", "export_text", "FORMATS", "NAME_PATTERN", "RIGID_ONLY_FORMATS",
        "StageError", "zero_filled",
    ),
    "_frames": ("Affine", "Frames", "TRANSLATIONS"),
    "_predictor": ("Predictor", "read_json", "stored_frames"),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
