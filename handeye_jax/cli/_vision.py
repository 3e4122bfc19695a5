"""``handeye-jax detect``: the landmarks found in a picture fill a capture of a dataset (thin
over :mod:`handeye_jax.vision`); :func:`add_detect_command` adds it to the command line."""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from .._core import (
    MAX_AREA_PX,
    MAX_DEG,
    MAX_MM,
    MIN_AREA_PX,
    InputError,
    StagedFiles,
    parse_int,
    same_file,
    write_output,
)
from ._types import PROG, landmarks_named, number_at_most, numbers, output_path, positive_int

if TYPE_CHECKING:  # the command imports OpenCV and tomlkit when it runs, not for --help
    import numpy as np
    from jaxtyping import Float, Int

_hand_position = numbers(MAX_MM, "mm", 3)


def _hand_angle(text: str) -> float:
    return numbers(MAX_DEG, "deg", 1)(text)[0]


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


def _cmd_detect(args: argparse.Namespace) -> int:
    from ..data import load_dataset
    from ..vision import fill_capture

    images = [args.capture_png, args.depth]
    out = output_path(args.out, "--out", images)
    in_place = out is None or same_file(out, args.dataset)
    written = _written(args.dataset, out, in_place)
    overlay = output_path(args.overlay, "--overlay", [*images, args.dataset, *written])
    dataset = load_dataset(args.dataset)
    if in_place:
        for path in written:
            output_path(path, "--dataset", images)
    target = _which_capture(args, dataset)
    _check_landmarks(args, dataset.n_landmarks)
    found = _found(args, dataset, overlay)
    new = fill_capture(dataset, found, target, hand_position_mm=args.hand_position,
                       hand_angle_deg=args.hand_angle)  # fmt: skip
    done = _write(args, new, out if not in_place else None, _staged_overlay(args, found, overlay))
    n, k = dataset.n_landmarks, len(found.landmarks)
    where = f"capture {len(dataset.captures) if target is None else target}"
    where += " (new)" if target is None else ""
    lost = sorted(set(range(n)) - set(found.landmarks.tolist()) - set(found.no_depth))
    left = "".join(f"; {landmarks_named(ms)} {why}, left out" for ms, why in
                   ((lost, "not found"), (found.no_depth, "without depth")) if ms)  # fmt: skip
    print(f"{k} of {n} landmarks found in {where}{left}; {done}")
    print(f"depth: {args.depth} read as 16-bit, {args.depth_scale_mm:g} mm per unit, aligned to "
          f"the picture pixel for pixel (as librealsense's align to colour or realsense2_camera's "
          f"aligned_depth_to_color image gives it); landmark depths "
          f"{found.depth_mm.min():.1f} to {found.depth_mm.max():.1f} mm")  # fmt: skip
    median = statistics.median(found.depth_mm.tolist())
    if not DEPTH_PLAUSIBLE_MM[0] <= median <= DEPTH_PLAUSIBLE_MM[1]:
        print(f"{PROG}: warning: the landmarks' median depth is {median:.1f} mm at "
              f"--depth-scale-mm {args.depth_scale_mm:g}: a camera over a tablet sees it at "
              f"{DEPTH_PLAUSIBLE_MM[0]:g} to {DEPTH_PLAUSIBLE_MM[1]:g} mm; check the depth "
              "scale (RealSense: its depth_scale in metres times 1000)", file=sys.stderr)
    return 0


#: Landmark depths a camera over a tablet sees, mm: outside, the depth scale is likely wrong.
DEPTH_PLAUSIBLE_MM = (20.0, 1000.0)


def _written(dataset: str, out: Path | None, in_place: bool) -> list:
    """The files ``detect`` writes: the dataset and its backup, or ``--out``."""
    from ..data import backup_path

    return [dataset, backup_path(dataset)] if in_place else [out]


def _found(args: argparse.Namespace, dataset, overlay: Path | None):
    """The landmarks the picture shows; on too few or too many blobs, the error (and the
    overlay of the blobs, when asked for)."""
    from ..vision import BlobCountError, DetectSettings, detect_landmarks

    if args.min_area > args.max_area:
        why = f"must be <= --max-area (got {args.min_area} > {args.max_area})"
        raise InputError(None, "--min-area", why)
    settings = DetectSettings(threshold=args.threshold, min_area_px=args.min_area,
                              max_area_px=args.max_area,
                              depth_scale_mm=args.depth_scale_mm)  # fmt: skip
    try:
        return detect_landmarks(args.capture_png, args.depth, dataset.tablet_px, settings,
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


def _staged_overlay(args: argparse.Namespace, found, overlay: Path | None) -> StagedFiles | None:
    """The overlay, waiting beside its target until the dataset is written."""
    if overlay is None:
        return None
    png = overlay_png(args.capture_png, found.image_px, found.depth_mm, found.landmarks)
    return StagedFiles({overlay: png}, "--overlay")


def _write(args: argparse.Namespace, new, out: Path | None, staged: StagedFiles | None) -> str:
    """``new`` written to ``out`` (``None``: the dataset in place), then the overlay put in
    place; what was done, for the printout."""
    from ..data import save_dataset, update_dataset

    try:
        if out is not None:
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
    return done


def add_detect_command(sub: argparse._SubParsersAction) -> None:
    """Add ``detect`` to the command line's subcommands ``sub``."""
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
    det.add_argument("depth", help="depth image (16-bit PNG, aligned to the picture)")
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
    det.add_argument(
        "--depth-scale-mm", type=number_at_most(100.0), default=1.0, metavar="MM",
        help="mm per unit of the depth image: RealSense's depth_scale (metres) times 1000, e.g. "
        "1 for 0.001 m units, 0.1 for 0.0001 m (default: %(default)s)",
    )  # fmt: skip
    det.add_argument("--min-area", type=positive_int, default=MIN_AREA_PX,
                     help="smallest blob, px² (default: %(default)s)")  # fmt: skip
    det.add_argument("--max-area", type=positive_int, default=MAX_AREA_PX,
                     help="largest blob, px² (default: %(default)s)")  # fmt: skip
    det.set_defaults(func=_cmd_detect, imports=("vision.detect_landmarks", "data.load_dataset"))
