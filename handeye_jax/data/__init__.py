"""Data in: a dataset file read and checked into a :class:`Dataset` (captures, touches,
camera, tablet), its landmark arrays as :class:`Observations` and the :class:`Rig` they were
taken on; dataset files written, edited in place and converted; the points CSV of
``predict``. Files come in here and nowhere else."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_dataset": ("Camera", "Capture", "check_distinct", "check_population", "Dataset"),
    "_dataset_io": (
        "backup_path", "check_tablet_px", "convert_path", "convert_to_v2", "dataset_from_document",
        "dataset_to_document", "dataset_to_toml", "FORMAT_V2", "load_dataset", "save_dataset",
        "update_dataset",
    ),
    "_layouts": ("snake_grid_px",),
    "_observations": ("Observations",),
    "_points": ("csv_number", "points_csv_text", "read_capture_columns", "read_points_csv"),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
