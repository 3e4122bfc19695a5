"""The plumbing every layer may use, without JAX: the one input error, reading with limits
(numbers, files, JSON), atomic writes, Ctrl-C handling, progress bars and the plain constants
the command line's help shows. Nothing here imports JAX, equinox or OpenCV (a test checks)."""

from __future__ import annotations

from ._lazy import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_atomic": (
        "check_folder_output", "check_output", "reason", "same_file", "StagedFiles",
        "write_folder_atomic", "write_output",
    ),
    "_constants": (
        "BATCH_WAVE", "BOOTSTRAP_FIGURE", "CAPTURE_RISE_MM", "CHANGES", "DERIVED_FILES",
        "DERIVED_FOLDER", "HELDOUT_ABOVE_MM", "HELDOUT_RISES_MM", "MAX_AREA_PX", "MAX_BOOTSTRAP",
        "MAX_DOT_PX", "MAX_TWIN_CAPTURES", "MIN_AREA_PX", "MORE_CAPTURE_FILES",
        "RECOMMENDED_CAPTURES", "REPORT_FIGURES", "REPORT_FORMATS", "SEARCH_PRESETS", "TWIN_FILES",
        "TWIN_SEED_RANGE", "WIDE_MODELS",
    ),
    "_errors": ("InputError",),
    "_io": (
        "csv_rows", "DIGEST_KEY", "document_digest", "load_json", "MAX_DATASET_BYTES",
        "MAX_IMAGE_BYTES", "MAX_RESULT_BYTES", "MAX_TEXT_BYTES", "parse_toml", "read_bytes",
        "read_text",
    ),
    "_progress": ("progress_bar",),
    "_schema": ("bounded", "count", "each", "length", "read", "spec", "to_document"),
    "_stages": ("Stages",),
    "_validate": (
        "describe", "join_key", "MAX_DEG", "MAX_GENERATIONS", "MAX_HELDOUT", "MAX_IMAGE_PIXELS",
        "MAX_LANDMARKS", "MAX_MEMBER_LANDMARKS", "MAX_MM", "MAX_POINTS", "MAX_POPULATION", "MAX_PX",
        "MAX_RAY_DEG", "MAX_RESTARTS", "MM_PER_TABLET_PX", "parse_float", "parse_int",
        "parse_numbers", "Reader",
    ),
    "_version": ("package_version",),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS, {"interrupts": "_interrupt"})
