"""``handeye-jax convert`` and ``plan``: a version-1 dataset written as version 2, and the
recommended pictures added to a dataset (thin over the API)."""

from __future__ import annotations

import argparse
from pathlib import Path

from .._core import (
    MAX_DEG,
    MAX_IMAGE_PIXELS,
    MAX_MM,
    InputError,
    check_output,
    same_file,
    write_output,
)
from .._core import RECOMMENDED_CAPTURES as RECOMMENDED
from ._types import landmarks_named, numbers


def _cmd_convert(args: argparse.Namespace) -> int:
    from ..data import FORMAT_V2, backup_path, convert_path, convert_to_v2, load_dataset

    old = Path(args.dataset)
    ds = load_dataset(old)
    if ds.version == 2:  # nothing to do is not a failure: scripts may convert unconditionally
        print(f"{old} is already {FORMAT_V2}; nothing written")
        return 0
    out = Path(args.out) if args.out is not None else convert_path(old)
    in_place = out.exists() and same_file(out, old)
    if in_place and not args.force:
        raise InputError(out, "--out", "is the dataset itself; give --force to convert it in "
                         "place (the old file is kept as a .bak beside it)")  # fmt: skip
    check_output(out, "--out", [] if in_place else [old])
    kept = None
    if out.exists():
        if not args.force:
            raise InputError(out, "--out", "exists; give --force to replace it (the old file "
                             "is kept as a .bak beside it) or choose another --out")  # fmt: skip
        kept = backup_path(out)
    convert_to_v2(old, out, overwrite=args.force, backup=kept)
    print(
        f"{old} converted to {FORMAT_V2}: {out} ({ds.n_landmarks} landmarks, 1 capture, "
        f"{ds.n_touches} touches)" + (f"; previous {out.name} kept as {kept}" if kept else "")
    )
    return 0


def _image_size(text: str) -> tuple[int, int]:
    w, h = numbers(MAX_MM, "px", 2)(text)
    if not (w == int(w) >= 8 and h == int(h) >= 8 and w * h <= MAX_IMAGE_PIXELS):
        why = f"at least 8 px each, at most {MAX_IMAGE_PIXELS:,} px in all (got {text!r})"
        raise argparse.ArgumentTypeError(f"needs 2 whole numbers, {why}")
    return int(w), int(h)


def _cmd_plan(args: argparse.Namespace) -> int:
    from ..data import backup_path, load_dataset, poses_csv_text, save_dataset, update_dataset
    from ..vision import plan_captures

    path = Path(args.dataset)
    out = None if args.out is None else check_output(args.out, "--out", [path])
    if args.poses_csv is not None:
        check_output(args.poses_csv, "--poses-csv", [path, *([out] if out else [])])
    if out is None:
        check_output(path, "--dataset")
        check_output(backup_path(path), "--dataset")
    ds = load_dataset(path)
    if ds.version == 1:
        raise InputError(path, "format", "is version 1: one capture; convert it first "
                         "(handeye-jax convert) to plan more pictures")  # fmt: skip
    if len(args.rise_mm) != len(args.turn_deg):
        raise InputError(None, "--turn-deg", f"needs one turn per --rise-mm (got "
                         f"{len(args.turn_deg)} turns, {len(args.rise_mm)} rises)")  # fmt: skip
    new, indices = plan_captures(ds, args.rise_mm, args.turn_deg)
    if out is not None:
        save_dataset(new, out)
        done = f"dataset written to {out}"
    elif (kept := update_dataset(path, new, keep_backup=True)) is not None:
        done = f"{path} updated (previous file kept as {kept})"
    else:
        done = f"{path} already holds them"
    cam = new.camera
    size = args.image_size_px or (round(2 * cam.cx_px), round(2 * cam.cy_px))
    views, why = _views(new, indices, size)
    print(f"{done}; the pictures to take, then detect each:")
    for k in [0, *indices]:
        print(_picture_line(new, k, out or path))
        if k in views and not views[k].in_view:
            print(f"    {_lost(views[k])}")
    if why:
        print(f"Not checked whether each picture shows every landmark: {why}; detect capture "
              "0, then plan again.")  # fmt: skip
    elif views:
        print(_views_line(views, size, args.image_size_px is not None))
    if args.poses_csv is not None:
        write_output(args.poses_csv, poses_csv_text([_tool_pose(new, k) for k in [0, *indices]]),
                     "--poses-csv")  # fmt: skip
        print(f"their tool0 poses written to {args.poses_csv} (kind,index,x_m,y_m,z_m,qx,qy,qz,"
              "qw; after the pictures, the poses the robot reports go back in with handeye-jax "
              "poses)")  # fmt: skip
    return 0


def _views(new, indices: list[int], size: tuple[int, int]) -> tuple[dict, str]:
    """Where each planned picture will show the landmarks (by capture index), or why that
    cannot be said yet."""
    from ..vision import planned_view

    views = {}
    try:
        for k in indices:
            c = new.captures[k]
            views[k] = planned_view(new, c.hand_position_mm, c.hand_angle_deg, size)
    except ValueError as e:
        return {}, str(e)
    return views, ""


def _tool_pose(new, k: int):
    """Capture ``k``'s flange (tool0 = hand frame) pose in the base frame."""
    from ..data import ToolPose, tool_pose_of_hand

    c = new.captures[k]
    R, t = tool_pose_of_hand(c.hand_position_mm, c.hand_angle_deg, new.hand_angle_zero_deg,
                             new.hand_angle_sign)  # fmt: skip
    return ToolPose("capture", k, R, t, 0)


def _picture_line(new, k: int, target: Path) -> str:
    """Capture ``k``'s pose (as the hand's and as tool0's) and the detect command that fills
    it."""
    from ..data import quaternion_from_rotation

    c = new.captures[k]
    x, y, z = (f"{v:g}" for v in c.hand_position_mm)
    seen = f"{len(c.landmarks)} of {new.n_landmarks} landmarks"
    pose = _tool_pose(new, k)
    q = " ".join(f"{v:.6f}" for v in quaternion_from_rotation(pose.R_base_tool))
    m = " ".join(f"{v / 1000:.4f}" for v in pose.t_base_tool_mm)
    return (f"  capture {k}: hand at ({x}, {y}, {z}) mm, hand angle {c.hand_angle_deg:g} deg "
            f"({seen}); tool0 in the base frame at [{m}] m, quaternion (x y z w) [{q}]: "
            f"handeye-jax detect CAP{k}.png DEP{k}.png --dataset {target} "
            f"--capture {k}")  # fmt: skip


def _views_line(views: dict, size: tuple[int, int], size_given: bool) -> str:
    """What the check of the planned pictures found, and how it was made."""
    mount = next(iter(views.values())).describe_mount()
    how = (f"a {size[0]} x {size[1]} px picture" + ("" if size_given else
           " (twice the principal point)") + ", by the rig's approximate model (camera "
           f"mount {mount})")  # fmt: skip
    if all(v.in_view for v in views.values()):
        return f"Each planned picture shows every landmark ({how})."
    return (f"Checked against {how}: plan other poses (less turn or rise) for the "
            "pictures that may lose landmarks.")  # fmt: skip


def _lost(view) -> str:
    """Which landmarks a planned picture loses, in words."""
    parts = []
    if view.outside:
        parts.append(f"{landmarks_named(view.outside)} outside the picture")
    if view.at_risk:
        parts.append(f"{landmarks_named(view.at_risk)} near its edge (may fall outside)")
    return "; ".join(parts)


def add_dataset_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``convert`` and ``plan`` to the command line's subcommands ``sub``."""
    add_convert_command(sub)
    rises = ",".join(f"{r:g}" for r, _ in RECOMMENDED)
    turns = ",".join(f"{t:g}" for _, t in RECOMMENDED)
    p = sub.add_parser(
        "plan",
        help="add the recommended pictures (captures) to a version-2 dataset",
        description="Add an empty capture for each further picture the toolkit recommends: "
        "higher than the dataset's first capture by each --rise-mm, with the hand turned by "
        "each --turn-deg, so that the tablet page lists their poses and 'detect --capture K' "
        "fills each. A pose the dataset already has is not added twice. Prints the poses, "
        "the detect command of each picture, and the landmarks each may not show (by the "
        "rig's approximate model, from what the first capture saw).",
    )
    p.add_argument("dataset", help="the version-2 dataset (TOML)")
    p.add_argument(
        "--rise-mm", type=numbers(MAX_MM, "mm"), default=rises,
        metavar="MM,MM", help=f"how much higher than the first capture each picture is, mm "
        f"(default: {rises})",
    )  # fmt: skip
    p.add_argument(
        "--turn-deg", type=numbers(MAX_DEG, "deg"), default=turns,
        metavar="DEG,DEG", help=f"each picture's hand angle minus the first capture's, deg; "
        f"write --turn-deg=-30,30 when the first is negative (default: {turns})",
    )  # fmt: skip
    p.add_argument(
        "--image-size-px", type=_image_size, metavar="W,H",
        help="the pictures' width and height, px, to check each planned picture against "
        "(default: twice the camera's principal point)",
    )  # fmt: skip
    p.add_argument(
        "--out", metavar="NEW.toml",
        help="write here (default: update DATASET in place, the old one kept as "
        "DATASET.<UTC time>.bak)",
    )  # fmt: skip
    p.add_argument(
        "--poses-csv", metavar="POSES.csv",
        help="also write each picture's tool0 pose (the hand frame; metres, quaternion x y z w) "
        "as a poses CSV, to drive the robot there (default: none, printed only)",
    )  # fmt: skip
    p.set_defaults(func=_cmd_plan, imports=("data.load_dataset", "vision.plan_captures"))


def add_convert_command(sub: argparse._SubParsersAction) -> None:
    """Add ``convert`` to the command line's subcommands ``sub``."""
    p = sub.add_parser(
        "convert",
        help="write a version-1 dataset as handeye-jax.dataset/2",
        description="Read a handeye-jax.dataset/1 file (the paper's single capture) and write "
        "the same data as handeye-jax.dataset/2: one [[captures]] at the hand angle where "
        "phi = 0, one [[touches]] per landmark. The values are identical (it calibrates to "
        "the same result); comments are not carried over. A file that is already version 2 "
        "is left alone (exit 0).",
    )
    p.add_argument("dataset", help="the version-1 dataset (TOML)")
    p.add_argument(
        "--out", metavar="NEW.toml",
        help="where to write (default: NAME.v2.toml beside NAME.toml); may be the dataset "
        "itself with --force",
    )  # fmt: skip
    p.add_argument(
        "--force", action="store_true",
        help="replace an existing --out (also the dataset itself); the replaced file is kept "
        "as OUT.<UTC time>.bak",
    )  # fmt: skip
    p.set_defaults(func=_cmd_convert, imports=("data.convert_to_v2",))
