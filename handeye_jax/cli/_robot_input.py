"""``handeye-jax poses`` and ``intrinsics``: what the robot and the camera already give, put
into a dataset (thin over :func:`~handeye_jax.apply_poses` and
:func:`~handeye_jax.read_intrinsics`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .._core import check_output
from ._types import number_at_most

DEFAULT_MAX_TILT_DEG = 1.0  # data.MAX_TILT_DEG, kept here so --help imports nothing


def _write(ds_path: Path, out: Path | None, new) -> str:
    """Write ``new`` to ``out``, or into the dataset in place (a backup kept); what was done."""
    from ..data import save_dataset, update_dataset

    if out is not None:
        save_dataset(new, out)
        return f"dataset written to {out}"
    kept = update_dataset(ds_path, new, keep_backup=True)
    if kept is None:
        return f"{ds_path} already holds these values; nothing written"
    return f"{ds_path} updated (previous file kept as {kept})"


def _outputs(args: argparse.Namespace, inputs: list[Path]) -> tuple[Path, Path | None]:
    from ..data import backup_path

    path = Path(args.dataset)
    out = None if args.out is None else check_output(args.out, "--out", inputs)
    if out is None:
        check_output(path, "--dataset")
        check_output(backup_path(path), "--dataset")
    return path, out


def _cmd_poses(args: argparse.Namespace) -> int:
    from ..data import TILT_WARN_DEG, apply_poses, load_dataset, read_poses_csv

    path, out = _outputs(args, [Path(args.dataset), Path(args.poses)])
    ds = load_dataset(path)
    poses = read_poses_csv(args.poses)
    new, report = apply_poses(ds, poses, max_tilt_deg=args.max_tilt_deg, path=args.poses)
    done = _write(path, out, new)
    kind, index, tilt = report.largest_tilt
    print(f"{len(report.captures)} capture(s) (hand_position, hand_angle) and "
          f"{len(report.touches)} touch(es) (hand_xy, hand_z, hand_angle) set from the flange "
          f"poses in {args.poses}; the tool is vertical within {tilt:.3f} deg (largest: "
          f"{kind} {index}); {done}")  # fmt: skip
    warning = report.warning(TILT_WARN_DEG)
    if warning:
        print(f"handeye-jax: warning: {warning}", file=sys.stderr)
    return 0


def _cmd_intrinsics(args: argparse.Namespace) -> int:
    from ..data import load_dataset, read_intrinsics

    path, out = _outputs(args, [Path(args.dataset), Path(args.camera_file)])
    camera = read_intrinsics(args.camera_file)
    ds = load_dataset(path)
    done = _write(path, out, ds.replace(camera=camera))
    lens = "no distortion" if camera.distortion is None else (
        "plumb_bob k1 k2 p1 p2 k3 = " + ", ".join(f"{c:g}" for c in camera.distortion))
    print(f"[camera] from {args.camera_file}: fx {camera.fx_px:g}, fy {camera.fy_px:g}, "
          f"cx {camera.cx_px:g}, cy {camera.cy_px:g} px; {lens}; {done}")  # fmt: skip
    return 0


def _out_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--out", metavar="NEW.toml",
        help="write here (default: update DATASET in place, the old one kept as "
        "DATASET.<UTC time>.bak)",
    )  # fmt: skip


def add_robot_input_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``poses`` and ``intrinsics`` to the command line's subcommands ``sub``."""
    p = sub.add_parser(
        "poses",
        help="set a dataset's hand poses from the robot's flange (tool0) poses",
        description="Read a CSV of flange poses in the robot's base frame, one row per capture "
        "or touch (columns kind,index; x_m,y_m,z_m or x_mm,y_mm,z_mm; and qx,qy,qz,qw, "
        "roll_deg,pitch_deg,yaw_deg, roll_rad,pitch_rad,yaw_rad, "
        "rotvec_x_rad,rotvec_y_rad,rotvec_z_rad or r00..r22), as `ros2 run tf2_ros tf2_echo "
        "base_link tool0` or a controller gives them, and write each capture's hand_position "
        "and hand_angle and each touch's hand_xy, hand_z and hand_angle into the version-2 "
        "dataset. The frame's z axis is the tool axis (tool0); the hand frame is that frame, "
        "and the hand angle follows the dataset's [hand_angle] convention. A tool tilted "
        "more than --max-tilt-deg from vertical is refused, one tilted more than 0.25 deg "
        "named in a warning.",
    )
    p.add_argument("dataset", help="the version-2 dataset (TOML)")
    p.add_argument("poses", help="CSV of flange poses (see above)")
    p.add_argument(
        "--max-tilt-deg", type=number_at_most(90.0), default=DEFAULT_MAX_TILT_DEG, metavar="DEG",
        help=f"refuse a pose whose tool axis is further than this from vertical, deg "
        f"(default {DEFAULT_MAX_TILT_DEG:g})",
    )  # fmt: skip
    _out_argument(p)
    p.set_defaults(func=_cmd_poses, imports=("data.apply_poses",))
    q = sub.add_parser(
        "intrinsics",
        help="set a dataset's [camera] from a camera_info YAML, an OpenCV file or a JSON",
        description="Read the camera's intrinsics and lens distortion from a ROS camera_info "
        "YAML (camera_calibration's file, or `ros2 topic echo --once .../camera_info`), an "
        "OpenCV calibration file (cv2.FileStorage YAML or XML: camera_matrix, "
        "distortion_coefficients) or a RealSense-style JSON (fx, fy, ppx, ppy, model, "
        "coeffs), and write them as the dataset's [camera] (fx, fy, cx, cy, px; distortion: "
        "plumb_bob k1 k2 p1 p2 k3).",
    )
    q.add_argument("camera_file", help="camera_info YAML, OpenCV YAML/XML or RealSense JSON")
    q.add_argument("--dataset", required=True, help="the dataset to set (TOML)")
    _out_argument(q)
    q.set_defaults(func=_cmd_intrinsics, jax=False)


__all__ = ["add_robot_input_commands"]
