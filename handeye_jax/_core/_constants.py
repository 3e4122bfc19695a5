"""Plain values shared by the heavy modules and the command line's help.

This module imports nothing, so that ``handeye-jax SUBCOMMAND --help`` can show them without
importing JAX, OpenCV or matplotlib (the modules that use them do).
"""

#: The figures ``report`` draws, each in every one of the formats.
REPORT_FIGURES = ("fig3_landmarks", "chains_stage1", "chains_stage2", "residuals", "convergence",
                  "loo")  # fmt: skip
#: The figure ``report`` draws only for a result with a bootstrap (``calibrate --bootstrap``).
BOOTSTRAP_FIGURE = "workspace_error_map"
#: The most resamples ``calibrate --bootstrap`` refits (each a whole calibration).
MAX_BOOTSTRAP = 10_000
REPORT_FORMATS = ("png", "svg")
#: The files :func:`~handeye_jax.write_twin` writes.
TWIN_FILES = ("dataset.toml", "truth.json", "heldout.csv", "capture.png", "depth.png")
#: What the loop of docs/twin.md makes from a twin beside its files (``detect --overlay``,
#: ``detect`` in place, ``calibrate --out``, ``report``): stale once the twin is replaced.
DERIVED_FILES = ("overlay.png", "dataset.toml.*.bak", "dataset.toml.bak", "result.json")
DERIVED_FOLDER = "result_report"
#: Seeds numpy's generators take: 0 to 2^63 - 1.
TWIN_SEED_RANGE = (0, 2**63 - 1)
#: Largest landmark dot, tablet px: larger dots merge with their neighbours.
MAX_DOT_PX = 50.0
#: The detector's default smallest and largest blob, image px².
MIN_AREA_PX = 2
MAX_AREA_PX = 80
#: A multi-capture twin's captures rise this far above the first one, mm (each but the
#: first jittered by ±5 mm): 3 captures spread over 85 to 95 mm.
CAPTURE_RISE_MM = 90.0
#: Held-out targets of a multi-capture twin are seen from captures this far above the first
#: (0: the first capture itself; others at new positions and hand angles), mm, and stand
#: this far above the display (0: drawn on it; else the top of an object), mm.
HELDOUT_RISES_MM = (0.0, 60.0)
HELDOUT_ABOVE_MM = (0.0, 50.0)
#: A multi-capture twin's pictures beyond the first: an old twin's are stale once replaced.
MORE_CAPTURE_FILES = ("capture_*.png", "depth_*.png")
#: The most pictures a twin draws.
MAX_TWIN_CAPTURES = 8
#: The parts :func:`~handeye_jax.change_truth` can change, and what each change draws (mm,
#: deg). Each move is a length drawn uniformly from its range in a uniform direction of the
#: x-y plane; each turn is an angle drawn uniformly from its range, either way.
CHANGES: dict[str, dict[str, tuple[float, float]]] = {
    # Another pen, or the same pen clamped anew: the tip (xp, yp) moves 3-15 mm.
    "pen": {"tip_move_mm": (3.0, 15.0)},
    # The tablet moved on the table: (xt, yt) moves 10-40 mm, it turns 2-8 deg about its
    # normal (γt), its tilts αt and βt are drawn afresh from RANGES.
    "tablet": {"move_mm": (10.0, 40.0), "turn_deg": (2.0, 8.0)},
    # The camera remounted: (xc, yc) moves 2-8 mm, each of αc, βc, γc turns 1-3 deg.
    "camera": {"move_mm": (2.0, 8.0), "turn_deg": (1.0, 3.0)},
}
#: The recommended further pictures: (rise above the first capture, mm; hand turn from it, deg).
RECOMMENDED_CAPTURES = ((40.0, 30.0), (80.0, -30.0))

#: Where a calibration's search ranges come from: ``estimate``, a box around a closed-form
#: estimate from the data (the default); ``paper``, the paper's Tables 5 and 6.
SEARCH_PRESETS = ("estimate", "paper")
#: Models whose random wide rigs ``simulate --wide`` draws.
WIDE_MODELS = ("htm", "dh")
#: Problems per device in one wave of a batch (``calibrate_batch``, ``calibrate-batch
#: --wave``): the most fitted at once, so that memory stays bounded and the progress bar moves.
BATCH_WAVE = 64
