"""Plain values shared by the heavy modules and the command line's help.

This module imports nothing, so that ``handeye-jax SUBCOMMAND --help`` can show them without
importing JAX, OpenCV or matplotlib (the modules that use them do).
"""

#: The files :func:`~handeye_jax.write_twin` writes.
TWIN_FILES = ("dataset.toml", "truth.json", "heldout.csv", "capture.png", "depth.png")
#: What the README's loop makes from a twin beside its files (``detect --overlay``, ``detect``
#: in place, ``calibrate --out``, ``report``): stale once the twin is replaced.
DERIVED_FILES = ("overlay.png", "dataset.toml.*.bak", "dataset.toml.bak", "result.json")
DERIVED_FOLDER = "result_report"
#: Seeds numpy's generators take: 0 to 2^63 - 1.
TWIN_SEED_RANGE = (0, 2**63 - 1)
#: Largest landmark dot, tablet px: larger dots merge with their neighbours.
MAX_DOT_PX = 50.0
#: The detector's default smallest and largest blob, image px².
MIN_AREA_PX = 2
MAX_AREA_PX = 80
