"""Data in: a dataset file read and checked into a :class:`Dataset` (captures, touches,
camera, tablet) and its landmark arrays as :class:`Observations`; dataset files written,
edited in place and converted; landmark layouts; the points CSV of ``predict``."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_convert": ("convert_path", "convert_to_v2"),
    "_dataset": ("Camera", "Capture", "check_distinct", "check_population", "Dataset"),
    "_edit": ("update_dataset",),
    "_hand_poses": ("apply_poses", "PoseReport"),
    "_intrinsics": ("read_intrinsics", "realsense_difference_px"),
    "_layouts": ("snake_grid_px",),
    "_moved": ("moved_base",),
    "_lens": ("distort_px", "DISTORTION_COEFFICIENTS", "DISTORTION_MODEL", "undistort_px"),
    "_observations": ("centre_landmark", "Observations"),
    "_poses": (
        "hand_angle_from_phi", "hand_phi_deg", "MAX_TILT_DEG", "poses_csv_text",
        "quaternion_from_rotation", "read_poses_csv", "rotation_from_quaternion",
        "rotation_from_rotvec", "rotation_from_rpy", "tilt_deg", "TILT_WARN_DEG",
        "tool_pose_of_hand", "ToolPose",
    ),
    "_points": ("csv_number", "points_csv_text", "read_capture_columns", "read_points_csv"),
    "_read": ("check_tablet_px", "dataset_from_document", "known_search_names", "load_dataset"),
    "_tables": ("FORMAT_V1", "FORMAT_V2"),
    "_write": ("backup_path", "dataset_to_document", "dataset_to_toml", "save_dataset"),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
