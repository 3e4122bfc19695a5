"""``handeye-jax simulate`` and ``evaluate``: a synthetic twin of the rig written, and a
calibration's held-out error on it (thin over :mod:`handeye_jax.twin`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from .._core import (
    CAPTURE_RISE_MM,
    CHANGES,
    DERIVED_FILES,
    DERIVED_FOLDER,
    HELDOUT_ABOVE_MM,
    HELDOUT_RISES_MM,
    MAX_DOT_PX,
    MAX_HELDOUT,
    TWIN_FILES,
    InputError,
    check_folder_output,
)
from .._core import MAX_TWIN_CAPTURES as MAX_CAPTURES
from ._types import number_at_most, seed, whole_number


def _heldout(text: str) -> int:
    return whole_number(text, 1, MAX_HELDOUT)


def _captures(text: str) -> int:
    return whole_number(text, 1, MAX_CAPTURES)


_dot_px = number_at_most(MAX_DOT_PX)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from ..twin import (
        PRESETS,
        change_truth,
        check_twin_folder,
        draw_truth,
        load_truth,
        simulate,
        write_twin,
    )

    out = Path(args.out_dir)
    if args.change and not args.truth:
        raise InputError(None, "--change", "needs --truth OLD_TRUTH.json, the rig that changed")
    check_folder_output(out, TWIN_FILES, "", [args.truth])
    stale = check_twin_folder(out, args.force)
    if args.truth:
        if args.dot_px is not None:
            raise InputError(None, "--dot-px", "the truth file sets the dot size (dot_px)")
        truth = old = load_truth(args.truth)
        if args.change:
            try:
                truth = change_truth(old, args.change, args.seed)
            except ValueError as e:
                raise InputError(args.truth, "--change", str(e)) from None
    else:
        truth = draw_truth(args.seed, dot_px=1.0 if args.dot_px is None else args.dot_px)
    twin = simulate(truth, PRESETS[args.preset], args.seed, exact=args.exact,
                    n_heldout=args.heldout, captures=args.captures)  # fmt: skip
    paths = write_twin(twin, out, force=args.force)
    how = "exact" if args.exact else "detected"
    if args.change:
        print(f"the {args.change} of {args.truth} changed (seed {args.seed}): "
              + _changes(old, truth))  # fmt: skip
    print(f"twin (seed {args.seed}, preset {args.preset}, image_px and depth {how}) written "
          f"to {out}: {', '.join(p.name for p in paths)}")  # fmt: skip
    if stale:
        names = ", ".join(str(p.relative_to(out)) for p in stale)
        print(f"removed what was made from the old twin: {names}")
    return 0


def _changes(old, new) -> str:
    """What differs between two truths' models, ``name old -> new unit``."""
    from ..models import HTMModel

    units = dict(zip(HTMModel.param_names, HTMModel.param_units, strict=True))
    return ", ".join(
        f"{n} {old.model[n]:.3f} -> {new.model[n]:.3f} {units[n]}"
        for n in HTMModel.param_names
        if new.model[n] != old.model[n]
    )


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from ..twin import evaluate_twin, format_evaluation

    print(format_evaluation(evaluate_twin(args.result, args.twin_dir)))
    return 0


def add_simulate_command(sub: argparse._SubParsersAction) -> None:
    """Add ``simulate`` to the command line's subcommands ``sub``."""
    sim = sub.add_parser(
        "simulate",
        help="a synthetic twin of the rig: pictures, dataset, truth and held-out targets",
        description="Draw a rig truth (or read --truth), render the camera's colour and depth "
        "images of the tablet, detect the landmarks, simulate the touches, and write "
        "dataset.toml, capture.png, depth.png, truth.json and heldout.csv into OUT_DIR, a new "
        "or empty folder (see --force).",
    )
    sim.add_argument("out_dir", help="folder to write: new or empty (created if missing)")
    sim.add_argument("--seed", type=seed, default=1,
                     help="seeds the truth and every noise draw, 0 to 2^63 - 1")  # fmt: skip
    sim.add_argument(
        "--preset",
        choices=("none", "paper", "harsh"),
        default="paper",
        help="noise preset (default paper: about the spread of Table 2)",
    )
    sim.add_argument(
        "--truth", metavar="TRUTH.json", help="use this rig truth (default: a draw from --seed)"
    )
    sim.add_argument(
        "--change", choices=tuple(CHANGES),
        help="with --truth: the same rig after this part changed, drawn by --seed within the "
        "documented ranges: pen, the tip moved 3-15 mm; tablet, moved 10-40 mm, turned 2-8 deg, "
        "tilts redrawn; camera, remounted 2-8 mm and 1-3 deg per angle (default: no change)",
    )  # fmt: skip
    sim.add_argument(
        "--exact",
        action="store_true",
        help="take image_px and depth from the truth instead of the detector",
    )
    sim.add_argument("--heldout", type=_heldout, default=20,
                     help=f"held-out targets, 1 to {MAX_HELDOUT:,} (default 20; with --captures, "
                     "this many for each capture and target height)")  # fmt: skip
    sim.add_argument(
        "--captures", type=_captures, default=1,
        help=f"pictures, 1 to {MAX_CAPTURES} (default 1, the paper's): the others from capture "
        f"poses rising to {CAPTURE_RISE_MM:g} mm above the first, at other positions and hand "
        "angles (capture_1.png, depth_1.png, ...); the touches then record the hand's height, "
        "and the held-out targets are seen from the first capture and one "
        f"{HELDOUT_RISES_MM[1]:g} mm above it at a new pose, on the display and "
        f"{HELDOUT_ABOVE_MM[1]:g} mm above it",
    )  # fmt: skip
    sim.add_argument(
        "--dot-px",
        type=_dot_px,
        help=f"side of the landmark dots, tablet px, at most {MAX_DOT_PX:g} (default 1, as the "
        "paper; not with --truth)",
    )
    sim.add_argument(
        "--force",
        action="store_true",
        help="write into a folder that is not empty: replace an old twin's files and remove "
        f"what was made from it ({', '.join(DERIVED_FILES)}, the figures in {DERIVED_FOLDER}/);"
        " other files are left as they are",
    )
    sim.set_defaults(func=_cmd_simulate, imports=("twin.simulate",))


def add_evaluate_command(sub: argparse._SubParsersAction) -> None:
    """Add ``evaluate`` to the command line's subcommands ``sub``."""
    ev = sub.add_parser(
        "evaluate",
        help="held-out touching error of a calibration on a synthetic twin",
        description="Send the hand to each held-out target of TWIN_DIR as RESULT predicts "
        "it (stage 1 and 2), see where the true pen lands, and print the mean and max "
        "touching error in mm and tablet px, beside the oracle (the true parameters) and the "
        "oracle with a stage-2 correction fitted on top (by the result's settings, with at most "
        "the default population and generations). RESULT must have been fitted on TWIN_DIR's "
        "dataset.toml.",
    )
    ev.add_argument("result", help="result file from 'calibrate --out'")
    ev.add_argument("twin_dir", help="folder written by 'simulate'")
    ev.set_defaults(func=_cmd_evaluate, imports=("twin.evaluate_twin",))
