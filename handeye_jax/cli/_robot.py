"""``handeye-jax predict`` and ``export``: what the robot's PC runs. Hand commands for image
points (NumPy only, for a result file as it was written), and a calibration for URDF, ROS 2,
OpenCV, a NumPy module, JSON or YAML."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .._core import MAX_MM, InputError, write_output

# names only: the exports (and NumPy) load when a command runs, not for --help
from ..robot import (
    DEFAULT_BASE_FRAME,
    DEFAULT_CAMERA_FRAME,
    DEFAULT_PARENT_LINK,
    DEFAULT_PEN_FRAME,
    FORMATS,
    NAME_PATTERN,
)
from ._runtime import start_jax
from ._types import PROG, numbers, output_path, whole_number


def _name(text: str) -> str:
    if not NAME_PATTERN.fullmatch(text):
        raise argparse.ArgumentTypeError(
            f"not a valid link or frame name: {text!r} (letters, digits and _, not first a digit)"
        )
    return text


def add_export_command(sub: argparse._SubParsersAction) -> None:
    """Add ``export`` to the command line's subcommands ``sub``."""
    p = sub.add_parser(
        "export",
        help="write a calibration as JSON, YAML, URDF, a ROS 2 launch file, OpenCV or Python",
        description="Write the fitted frames for other tools: json / yaml (named frames with "
        "units, axes and the components the data did not determine, as null), urdf (a xacro "
        "snippet: fixed joints from the flange to the camera's optical frame and the pen tip; "
        "metres, radians), ros2 (static_transform_publisher nodes and commands; metres, "
        "quaternion x y z w), opencv (R_cam2gripper, t_cam2gripper as cv2.calibrateHandEye "
        "gives them, mm, with cv2.FileStorage), python (a NumPy-only predictor module). "
        "Formats that cannot say 'unknown' write 0 there, say so in the file, and warn.",
    )
    p.add_argument("result", help="result file from 'calibrate --out'")
    p.add_argument(
        "--format", required=True, choices=FORMATS, dest="fmt",
        metavar="{" + ",".join(FORMATS) + "}",
        help="json/yaml: named frames with units and what the data did not determine; urdf: a "
        "xacro snippet; ros2: static_transform_publisher and a launch snippet; opencv: "
        "cv2.calibrateHandEye's R_cam2gripper, t_cam2gripper; python: a numpy-only predictor",
    )  # fmt: skip
    p.add_argument("--out", metavar="FILE", help="write here (default: standard output)")
    p.add_argument(
        "--stage", type=whole_number, choices=(1, 2), default=None,
        help="the stage the file carries (default: the one the calibration chose to deploy); "
        "urdf and ros2 hold stage 1 only and refuse a calibration that deploys stage 2 unless "
        "--stage 1 is given",
    )  # fmt: skip
    p.add_argument(
        "--parent-link", type=_name, default=DEFAULT_PARENT_LINK, metavar="LINK",
        help=f"the flange link (urdf, ros2; default {DEFAULT_PARENT_LINK})",
    )  # fmt: skip
    p.add_argument(
        "--camera-frame", type=_name, default=DEFAULT_CAMERA_FRAME, metavar="NAME",
        help=f"the camera's optical frame (urdf, ros2; default {DEFAULT_CAMERA_FRAME})",
    )  # fmt: skip
    p.add_argument(
        "--pen-frame", type=_name, default=DEFAULT_PEN_FRAME, metavar="NAME",
        help=f"the pen tip frame (urdf, ros2; default {DEFAULT_PEN_FRAME})",
    )  # fmt: skip
    p.add_argument(
        "--base-frame", type=_name, default=DEFAULT_BASE_FRAME, metavar="NAME",
        help=f"the robot's base frame (easy_handeye; default {DEFAULT_BASE_FRAME})",
    )  # fmt: skip
    p.add_argument(
        "--camera-z-mm", type=_length_mm, metavar="MM",
        help="the camera's optical centre along the flange's z axis, mm, measured: the data "
        "does not determine it; with the touches' hand heights the pen tip's z follows (default: "
        "none; the file writes 0 there and says so)",
    )  # fmt: skip
    p.add_argument(
        "--pen-z-mm", type=_length_mm, metavar="MM",
        help="the pen tip along the flange's z axis, mm, measured (instead of --camera-z-mm "
        "when the calibration determined z_pen - z_camera; else as well; default: none)",
    )  # fmt: skip
    p.set_defaults(func=_cmd_export, imports=("calibration.load_frames", "robot.export_text"))


def _length_mm(text: str) -> float:
    return numbers(MAX_MM, "mm", 1)(text)[0]


def _cmd_export(args: argparse.Namespace) -> int:
    out = output_path(args.out, "--out", [args.result])
    names = (args.parent_link, args.camera_frame, args.pen_frame)
    if len(set(names)) != 3:
        print(f"{PROG}: error: --parent-link, --camera-frame and --pen-frame must differ "
              f"(got {', '.join(names)})", file=sys.stderr)  # fmt: skip
        return 2
    from ..calibration import load_frames  # JAX: not imported for --help
    from ..robot import (
        FrameNames,
        StageError,
        carried_stage,
        check_parses,
        export_text,
        filled_translations_mm,
        with_heights,
        zero_filled,
    )

    frames = load_frames(args.result)
    try:
        stage = carried_stage(frames, args.fmt, args.stage)
    except StageError as e:
        raise InputError(args.result, "--format", str(e)) from None
    try:
        frames = with_heights(frames, args.camera_z_mm, args.pen_z_mm)
    except ValueError as e:
        flag = "--pen-z-mm" if args.camera_z_mm is None else "--camera-z-mm"
        raise InputError(args.result, flag, str(e)) from None
    names = FrameNames(args.parent_link, args.camera_frame, args.pen_frame, args.base_frame)
    text = export_text(frames, args.fmt, names=names, source=str(args.result), stage=stage)
    check_parses(text, args.fmt)
    zeros = zero_filled(frames, args.fmt)
    if zeros:
        print(f"{PROG}: warning: {', '.join(zeros)} not determined by the data: written as 0 "
              f"in the {args.fmt} file, which says so; give --camera-z-mm (the camera's "
              "optical centre along the flange's z, measured)" + (
                  f"; t_hand_pen_mm.z written as z_pen - z_camera = "
                  f"{frames.pen_minus_camera_z_mm:.3f} mm above it"
                  if filled_translations_mm(frames)[3] and args.fmt != "easy_handeye" else ""),
              file=sys.stderr)  # fmt: skip
    return _emit(text, out, f"{args.fmt} export (stage {stage})")


def _cmd_predict(args: argparse.Namespace) -> int:
    from ..data import points_csv_text, read_capture_columns, read_points_csv
    from ..robot import Predictor, check_reach, result_reach, stored_result

    out = output_path(args.out, "--out", [args.result, args.points])
    checked = stored_result(args.result)  # NumPy only: no JAX for a file as it was written
    if checked is None:  # older or edited: validated, its frames checked against its parameters
        start_jax()
        from ..calibration import load_frames

        checked = (load_frames(args.result), result_reach(args.result))
    predictor = Predictor.from_frames(*checked)
    header, rows, values = read_points_csv(args.points)
    position, angle = read_capture_columns(args.points, header, rows)
    stage = predictor.stage if args.stage is None else args.stage
    hand_xy = predictor.hand_command(values[:, :2], values[:, 2], values[:, 3], stage=stage,
                                     capture_position_mm=position, capture_hand_angle_deg=angle,
                                     axes=predictor.axes)  # fmt: skip
    check_reach(args.points, hand_xy, predictor.reach.including(position), args.result)
    text = points_csv_text(header, rows, hand_xy)
    chosen = "the stage the calibration deploys" if stage == predictor.stage else (
        f"not the stage the calibration deploys, {predictor.stage}")  # fmt: skip
    return _emit(text, out, f"{len(rows)} hand commands (stage {stage}, {chosen}; mm)")


def add_predict_command(sub: argparse._SubParsersAction) -> None:
    """Add ``predict`` to the command line's subcommands ``sub``."""
    pre = sub.add_parser(
        "predict",
        help="hand commands for image points",
        description="Read a CSV with header u,v,depth,hand_angle (px, px, mm, deg) and write it "
        "back with hand_x,hand_y (mm, robot base frame) added: where to send the hand so "
        "that the pen touches each point; and hand_z (mm) when the calibration's touches "
        "recorded the hand's heights. Optional columns capture_x,capture_y,capture_z (mm) "
        "and capture_angle (deg): the hand pose each point's picture was taken from "
        "(default: the calibration's first capture).",
    )
    pre.add_argument("result", help="result file from 'calibrate --out'")
    pre.add_argument("points", help="CSV with header u,v,depth,hand_angle")
    pre.add_argument(
        "--out", metavar="OUT.csv", help="write the CSV here (default: standard output)"
    )
    pre.add_argument(
        "--stage", type=whole_number, choices=(1, 2), default=None,
        help="2: eq. (25) with the affine correction; 1: eq. (8), model only (default: the "
        "stage the calibration chose to deploy, which its summary names)",
    )  # fmt: skip
    pre.set_defaults(func=_cmd_predict, jax=False)  # only for files it must check (see there)


def _emit(text: str, out: Path | None, what: str) -> int:
    """``text`` written to ``out`` (saying so, as ``what written to OUT``), or to standard
    output."""
    if out is None:
        sys.stdout.write(text)
    else:
        write_output(out, text, "--out")
        print(f"{what} written to {out}")
    return 0
