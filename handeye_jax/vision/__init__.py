"""The camera's pictures: landmark detection and matching in a colour and depth picture
(OpenCV), and the pictures to take (capture planning)."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_captures": ("plan_captures", "planned_view", "PlannedView"),
    "_detect": (
        "BlobCountError", "depth_at", "detect_landmarks", "Detection", "DetectSettings",
        "fill_capture", "fill_dataset", "find_blobs", "match_blobs", "MAX_ANISOTROPY",
        "order_blobs", "overlay_image", "PLAUSIBLE_TURN_DEG", "read_image",
    ),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
