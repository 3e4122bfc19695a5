"""``handeye-jax simulate``, ``detect`` and ``evaluate``: thin commands over the twin's API.

:func:`add_twin_commands` adds them to the command line (:mod:`handeye_jax.cli`); the work is
in :mod:`~handeye_jax._simulate`, :mod:`~handeye_jax._detect` and :mod:`~handeye_jax._evaluate`.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from .._core import (
    CAPTURE_RISE_MM,
    CHANGES,
    DERIVED_FILES,
    DERIVED_FOLDER,
    HELDOUT_ABOVE_MM,
    HELDOUT_RISES_MM,
    MAX_AREA_PX,
    MAX_DEG,
    MAX_DOT_PX,
    MAX_HELDOUT,
    MAX_MM,
    MIN_AREA_PX,
    TWIN_FILES,
    InputError,
    StagedFiles,
    check_folder_output,
    check_output,
    parse_float,
    parse_int,
    parse_numbers,
    same_file,
    write_output,
)
from .._core import MAX_TWIN_CAPTURES as MAX_CAPTURES
from .._core import TWIN_SEED_RANGE as SEED_RANGE

if TYPE_CHECKING:  # the commands import OpenCV, JAX and tomlkit when they run, not for --help
    import numpy as np
    from jaxtyping import Float, Int


def _whole_number(text: str, lo: int, hi: int | None = None) -> int:
    try:
        v = parse_int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if v < lo or hi is not None and v > hi:
        most = f"{lo} to {hi:,}" if hi is not None else f"at least {lo}"
        raise argparse.ArgumentTypeError(f"must be {most} (got {v})")
    return v


def _positive_int(text: str) -> int:
    return _whole_number(text, 1)


def _heldout(text: str) -> int:
    return _whole_number(text, 1, MAX_HELDOUT)


def _captures(text: str) -> int:
    return _whole_number(text, 1, MAX_CAPTURES)


def _twin_seed(text: str) -> int:
    try:
        v = parse_int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if not SEED_RANGE[0] <= v <= SEED_RANGE[1]:
        why = f"must be 0 to 2^63 - 1: numpy's generators take no other seed (got {v})"
        raise argparse.ArgumentTypeError(why)
    return v


def _dot_px(text: str) -> float:
    try:
        v = parse_float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < v <= MAX_DOT_PX:
        raise argparse.ArgumentTypeError(f"must be > 0 and at most {MAX_DOT_PX:g} (got {text})")
    return v


def _output(path: str | None, option: str, inputs: list) -> Path | None:
    """The output file of ``option``, checked before the work (see ``check_output``)."""
    return None if path is None else check_output(path, option, inputs)


def overlay_png(
    capture: str | Path,
    points_px: Float[np.ndarray, "n 2"],
    depth_mm: Float[np.ndarray, " n"] | None,
    landmarks: Int[np.ndarray, " n"] | None = None,
) -> bytes:
    """The picture with each point circled and numbered (its landmark index, default 0, 1, …;
    with its depth in mm, if given), PNG."""
    from ..twin import encode_png
    from ..vision import overlay_image, read_image

    image = read_image(capture)
    if depth_mm is None:
        labels = [f"?{i}" for i in range(len(points_px))]
    else:
        ids = range(len(depth_mm)) if landmarks is None else landmarks
        labels = [f"{m}: {z:.0f} mm" for m, z in zip(ids, depth_mm, strict=True)]
    return encode_png(overlay_image(image, points_px, labels))


def write_overlay(
    capture: str | Path,
    points_px: Float[np.ndarray, "n 2"],
    depth_mm: Float[np.ndarray, " n"] | None,
    out: Path,
) -> None:
    """:func:`overlay_png` written to ``out`` atomically."""
    write_output(out, overlay_png(capture, points_px, depth_mm), "--overlay")


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


def _numbers(text: str, n: int, limit: float, unit: str) -> list[float]:
    try:
        return parse_numbers(text, limit, unit, n)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _hand_position(text: str) -> list[float]:
    return _numbers(text, 3, MAX_MM, "mm")


def _hand_angle(text: str) -> float:
    return _numbers(text, 1, MAX_DEG, "deg")[0]


def _capture_index(text: str) -> int | str:
    if text == "new":
        return text
    try:
        v = parse_int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a capture index (0, 1, ...) or 'new' (got "
                                          f"{text!r})") from None  # fmt: skip
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be a capture index, 0 or more, or 'new' (got {v})")
    return v


def _landmark_list(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        try:
            out.append(parse_int(part.strip()))
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a landmark index: {part.strip()!r}") from None
    return out


def _which_capture(args: argparse.Namespace, dataset) -> int | None:
    """The capture ``detect`` writes (``None``: a new one), checked before any work."""
    n_caps = len(dataset.captures)
    if dataset.version == 1:
        used = [o for o, v in (("--capture", args.capture not in (None, 0)),
                               ("--hand-position", args.hand_position is not None),
                               ("--hand-angle", args.hand_angle is not None),
                               ("--landmarks", args.landmarks is not None)) if v]  # fmt: skip
        if used:
            raise InputError(None, used[0], f"{args.dataset} is version 1: one capture of "
                             "every landmark; convert it first (handeye-jax convert) for "
                             "several captures or missing landmarks")  # fmt: skip
        return 0
    if args.capture is None:
        if n_caps != 1:
            raise InputError(None, "--capture", f"{args.dataset} has {n_caps} captures: say "
                             f"which (0 to {n_caps - 1}) or 'new'")  # fmt: skip
        return 0
    if args.capture == "new":
        for option, value in (("--hand-position", args.hand_position),
                              ("--hand-angle", args.hand_angle)):  # fmt: skip
            if value is None:
                raise InputError(None, option, "a new capture (--capture new) needs the hand "
                                 "pose it was taken from: --hand-position x,y,z (mm) and "
                                 "--hand-angle (deg)")  # fmt: skip
        return None
    if args.capture >= n_caps:
        raise InputError(None, "--capture", f"capture {args.capture} does not exist: "
                         f"{args.dataset} has {n_caps} (0 to {n_caps - 1}); 'new' appends "
                         "one")  # fmt: skip
    return args.capture


def _check_landmarks(args: argparse.Namespace, n: int) -> None:
    if args.landmarks is None:
        return
    for m in args.landmarks:
        if not 0 <= m < n:
            raise InputError(None, "--landmarks", f"landmark {m} does not exist: "
                             f"{args.dataset} has {n} (0 to {n - 1})")  # fmt: skip
    if len(set(args.landmarks)) != len(args.landmarks):
        raise InputError(None, "--landmarks", "names a landmark twice")
    if len(args.landmarks) < 4:
        raise InputError(None, "--landmarks", f"names {len(args.landmarks)}; ordering blobs "
                         "needs at least 4 landmarks in the picture")  # fmt: skip


def _listed(ms) -> str:
    ms = list(ms)
    return ("landmark " if len(ms) == 1 else "landmarks ") + ", ".join(map(str, ms))


def _cmd_detect(args: argparse.Namespace) -> int:
    from ..data import backup_path, load_dataset, save_dataset, update_dataset
    from ..vision import BlobCountError, DetectSettings, detect_landmarks, fill_capture

    images = [args.capture_png, args.depth]
    out = _output(args.out, "--out", images)
    in_place = out is None or same_file(out, args.dataset)
    written = [args.dataset, backup_path(args.dataset)] if in_place else [out]
    overlay = _output(args.overlay, "--overlay", [*images, args.dataset, *written])
    dataset = load_dataset(args.dataset)
    if in_place:
        for path in written:
            _output(path, "--dataset", images)
    target = _which_capture(args, dataset)
    _check_landmarks(args, dataset.n_landmarks)
    if args.min_area > args.max_area:
        why = f"must be <= --max-area (got {args.min_area} > {args.max_area})"
        raise InputError(None, "--min-area", why)
    settings = DetectSettings(threshold=args.threshold, min_area_px=args.min_area,
                              max_area_px=args.max_area)  # fmt: skip
    try:
        found = detect_landmarks(args.capture_png, args.depth, dataset.tablet_px, settings,
                                 partial=dataset.version == 2,
                                 landmarks=args.landmarks)  # fmt: skip
    except BlobCountError as e:
        if dataset.version == 1 and len(e.blobs.image_px) < dataset.n_landmarks:
            e = e.with_note("; a version-2 dataset may leave landmarks out of a picture "
                            "(handeye-jax convert)")  # fmt: skip
        if overlay is not None:
            write_overlay(args.capture_png, e.blobs.image_px, None, overlay)
            e = e.with_note(f"; overlay in {overlay}")
        raise e from None
    new = fill_capture(dataset, found, target, hand_position_mm=args.hand_position,
                       hand_angle_deg=args.hand_angle)  # fmt: skip
    # The overlay waits beside its target and goes in place only once the dataset is written.
    staged = None
    if overlay is not None:
        png = overlay_png(args.capture_png, found.image_px, found.depth_mm, found.landmarks)
        staged = StagedFiles({overlay: png}, "--overlay")
    try:
        if not in_place:
            save_dataset(new, out)
            done = f"dataset written to {out}"
        elif (kept := update_dataset(args.dataset, new, keep_backup=True)) is not None:
            # In place: only the capture's values change; the file's comments and layout stay.
            done = f"{args.dataset} updated (previous file kept as {kept})"
        else:
            done = f"{args.dataset} already holds them"
    except BaseException:
        if staged is not None:
            staged.discard()
        raise
    if staged is not None:
        staged.commit()
    n, k = dataset.n_landmarks, len(found.landmarks)
    where = f"capture {len(dataset.captures) if target is None else target}"
    where += " (new)" if target is None else ""
    lost = sorted(set(range(n)) - set(found.landmarks.tolist()) - set(found.no_depth))
    left = "".join(f"; {_listed(ms)} {why}, left out" for ms, why in
                   ((lost, "not found"), (found.no_depth, "without depth")) if ms)  # fmt: skip
    print(f"{k} of {n} landmarks found in {where}{left}; {done}")
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from ..twin import evaluate_twin, format_evaluation

    print(format_evaluation(evaluate_twin(args.result, args.twin_dir)))
    return 0


def add_twin_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``simulate``, ``detect`` and ``evaluate`` to the command line's subparsers."""
    sim = sub.add_parser(
        "simulate",
        help="a synthetic twin of the rig: pictures, dataset, truth and held-out targets",
        description="Draw a rig truth (or read --truth), render the camera's colour and depth "
        "images of the tablet, detect the landmarks, simulate the touches, and write "
        "dataset.toml, capture.png, depth.png, truth.json and heldout.csv into OUT_DIR, a new "
        "or empty folder (see --force).",
    )
    sim.add_argument("out_dir", help="folder to write: new or empty (created if missing)")
    sim.add_argument("--seed", type=_twin_seed, default=1,
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

    det = sub.add_parser(
        "detect",
        help="find the landmarks in the camera's picture and fill a capture's image_px and depth",
        description="Find the dark landmark dots in CAPTURE (8-bit) and read their depth from "
        "DEPTH (16-bit PNG, mm, 0 = none); write the dataset with that capture's image_px and "
        "depth filled in, every other field as it was. A version-1 dataset has one capture, "
        "which must show every landmark. In a version-2 dataset the picture fills capture "
        "--capture K (or a new one, with its hand pose), and landmarks it does not show are "
        "left out of that capture (the printout names them).",
    )
    det.add_argument("capture_png", metavar="capture", help="colour picture of the tablet (PNG)")
    det.add_argument("depth", help="depth image (16-bit PNG, mm)")
    det.add_argument("--dataset", required=True, help="the dataset to fill (TOML)")
    det.add_argument(
        "--capture", type=_capture_index, metavar="K|new",
        help="which capture of a version-2 dataset the picture is, 0-based, or 'new' to append "
        "one (default: 0 when the dataset has one capture; else required)",
    )  # fmt: skip
    det.add_argument(
        "--hand-position", type=_hand_position, metavar="X,Y,Z",
        help="the hand's position when the picture was taken, mm, base frame; write "
        "--hand-position=-20,50,300 when x is negative (default: the capture's own; required "
        "with --capture new)",
    )  # fmt: skip
    det.add_argument(
        "--hand-angle", type=_hand_angle, metavar="DEG",
        help="the hand angle when the picture was taken, deg, as the controller reports it "
        "(default: the capture's own; required with --capture new)",
    )  # fmt: skip
    det.add_argument(
        "--landmarks", type=_landmark_list, metavar="M,M,...",
        help="the landmarks the picture shows, when the blobs alone cannot tell which they are "
        "(default: found from the blobs' layout)",
    )  # fmt: skip
    det.add_argument(
        "--out",
        metavar="NEW.toml",
        help="write here (default: update DATASET in place, the old one kept as "
        "DATASET.<UTC time>.bak)",
    )
    det.add_argument(
        "--overlay",
        metavar="OVERLAY.png",
        help="write the picture with the detected centroids numbered in landmark order "
        "(default: none)",
    )
    det.add_argument(
        "--threshold", choices=("otsu", "adaptive"), default="otsu",
        help="how dots are told from the background: Otsu's threshold on the top-hat, or "
        "OpenCV's adaptive threshold",
    )  # fmt: skip
    det.add_argument("--min-area", type=_positive_int, default=MIN_AREA_PX,
                     help="smallest blob, px² (default: %(default)s)")  # fmt: skip
    det.add_argument("--max-area", type=_positive_int, default=MAX_AREA_PX,
                     help="largest blob, px² (default: %(default)s)")  # fmt: skip
    det.set_defaults(func=_cmd_detect, imports=("vision.detect_landmarks", "data.load_dataset"))

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
