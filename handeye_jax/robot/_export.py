"""Calibrations for other tools: ``handeye-jax export RESULT.json --format FORMAT``.

Every format holds the same :class:`~handeye_jax.Frames`, each in its ecosystem's own terms:

* ``json``, ``yaml``: the frames document (:meth:`Frames.to_dict`): named transforms with their
  axes, units, the hand-angle convention, the capture pose, stage 2, and which components the
  data did not determine (``null``, never a silent 0).
* ``urdf``: a xacro snippet, fixed joints from the flange link to the camera's optical frame and
  the pen tip, in metres and fixed-axis roll-pitch-yaw radians.
* ``ros2``: a launch file of ``tf2_ros static_transform_publisher`` nodes (metres, quaternion
  x y z w), with the same commands for a shell in its header.
* ``opencv``: ``R_cam2gripper`` and ``t_cam2gripper`` as ``cv2.calibrateHandEye`` returns them
  (plus the rest of the chain), written with ``cv2.FileStorage``.
* ``python``: a standalone, NumPy-only module with the fitted numbers inside.
* ``easy_handeye``: the YAML easy_handeye (ROS) stores an eye-on-hand calibration in: its
  ``parameters`` (frames named) and ``transformation`` (``x y z`` in metres, ``qx qy qz qw``)
  of the camera's optical frame in the flange frame.

URDF, ROS and OpenCV cannot hold "unknown": they get 0 for an undetermined component, with a
comment in the file saying so (:func:`zero_filled` lists them for the command's warning).

Every file says which stage it carries: by default the one the calibration chose to deploy
(:attr:`Frames.deploy_stage`). URDF, ROS 2 and easy_handeye hold rigid transforms only,
stage 1: they refuse a calibration that deploys stage 2 unless stage 1 is asked for
(:class:`StageError`).
Rotation conversions are jaxlie's. jaxlie, OpenCV and PyYAML are imported when a format
needs them: the command line builds its parser from this module's constants.
"""

from __future__ import annotations

import ast
import inspect
import json
import math
import shlex
import textwrap

import numpy as np

from .._core import package_version
from ..data import distort_px, undistort_px
from . import _npchain
from ._frames import AXES, REASONS, Frames
from ._heights import filled_translations_mm
from ._names import (
    DEFAULT_TABLET_FRAME,
    FORMATS,
    ZERO_FILLED_FORMATS,
    FrameNames,
)

#: Formats that hold rigid transforms only: stage 1 (eq. 8), never stage 2's affine maps.
RIGID_ONLY_FORMATS = ("urdf", "ros2", "easy_handeye")


class StageError(ValueError):
    """An export asked to carry a stage its format cannot hold."""


def carried_stage(frames: Frames, fmt: str, stage: int | None = None) -> int:
    """The stage an export of ``fmt`` carries: ``stage``, else the one the calibration deploys;
    :class:`StageError` if ``fmt`` cannot hold it (stage 2 in URDF or ROS 2)."""
    stage = frames.deploy_stage if stage is None else int(stage)
    if stage not in (1, 2):
        raise ValueError(f"stage must be 1 or 2 (got {stage})")
    if stage == 2 and fmt in RIGID_ONLY_FORMATS:
        chose = ("the calibration deploys stage 2 (the stage its result chose, or stage 2 for "
                 "a result that records no choice)" if frames.deploy_stage == 2
                 else "stage 2 was asked for")  # fmt: skip
        raise StageError(
            f"{chose}, and a {fmt} file holds rigid transforms only: stage 2's affine "
            "correction (eq. 25) cannot go into it. Export --stage 1 for the frames alone "
            "(eq. 8), or --format json, yaml, opencv or python, which carry stage 2"
        )  # fmt: skip
    return stage


def _stage_line(frames: Frames, stage: int) -> str:
    what = ("stage 2, eq. (25): the frames with the affine correction A1, A2" if stage == 2
            else "stage 1, eq. (8): the frames alone, no affine correction")  # fmt: skip
    chose = (
        "the stage the calibration chose to deploy"
        if stage == frames.deploy_stage
        else f"not the stage the calibration chose to deploy (stage {frames.deploy_stage})"
    )
    return f"Carries {what}; {chose}."


MM_PER_M = 1000.0


def _version() -> str:
    return package_version()


def zero_filled(frames: Frames, fmt: str) -> list[str]:
    """The components ``fmt`` writes as 0 because the data did not determine them."""
    if fmt not in ZERO_FILLED_FORMATS:
        return []
    carried = {
        "urdf": ("t_hand_camera_mm", "t_hand_pen_mm"),
        "ros2": ("t_hand_camera_mm", "t_hand_pen_mm"),
        "opencv": ("t_hand_camera_mm", "t_hand_pen_mm", "t_base_tablet_mm"),
        "easy_handeye": ("t_hand_camera_mm",),
    }[fmt]
    zeros = [c for c in frames.undetermined if c.split(".")[0] in carried]
    if filled_translations_mm(frames)[3] and "t_hand_pen_mm.z" in zeros:
        zeros.remove("t_hand_pen_mm.z")  # written relative to the camera's: z_pen - z_camera
    return zeros


def rpy_radians(R: np.ndarray) -> tuple[float, float, float]:
    """Fixed-axis roll, pitch, yaw (URDF's ``rpy``: ``R = Rz(yaw)·Ry(pitch)·Rx(roll)``), rad."""
    import jax  # here, not at the top: export's --help imports no JAX
    import jaxlie

    with jax.enable_x64(True):
        rpy = jaxlie.SO3.from_matrix(np.asarray(R, dtype=np.float64)).as_rpy_radians()
        return float(rpy.roll), float(rpy.pitch), float(rpy.yaw)


def quaternion_xyzw(R: np.ndarray) -> tuple[float, float, float, float]:
    """The unit quaternion of ``R`` in ROS's order ``(x, y, z, w)``, with ``w >= 0``."""
    import jax  # here, not at the top: export's --help imports no JAX
    import jaxlie

    with jax.enable_x64(True):
        w, x, y, z = (float(v) for v in jaxlie.SO3.from_matrix(np.asarray(R, float)).wxyz)
    return (x, y, z, w) if w >= 0 else (-x, -y, -z, -w)


def _m(v: np.ndarray) -> list[float]:
    """A translation in mm as metres."""
    return [float(x) / MM_PER_M for x in v]


def _num(x: float) -> str:
    return repr(float(x))


def _wrap(lines: list[str], width: int = 96) -> list[str]:
    """Long comment lines folded at ``width``, continuations indented under their line."""
    out = []
    for line in lines:
        indent = " " * (len(line) - len(line.lstrip()) + 2)
        out += textwrap.wrap(line, width, subsequent_indent=indent, break_on_hyphens=False) or [""]
    return out


def _header_lines(frames: Frames, fmt: str, source: str, stage: int) -> list[str]:
    """The lines every text export starts with (without comment markers)."""
    # Escaped, so that no file name can end a comment or a string of the file it goes into.
    source = source.encode("unicode_escape").decode("ascii").replace('"', "'")
    src = f" from {source}" if source else ""
    model = f" (model {frames.model})" if frames.model else ""
    return [f"Generated by handeye-jax {_version()} (export, format {fmt}){src}{model}.",
            _stage_line(frames, stage)]  # fmt: skip


def _undetermined_lines(frames: Frames, fmt: str) -> list[str]:
    zeros = zero_filled(frames, fmt)
    *_, relative = filled_translations_mm(frames)
    lines = []
    if frames.given:
        lines.append(
            "GIVEN by the user, not determined by the calibration data (mm): "
            + ", ".join(f"{c} = {getattr(frames, c.split('.')[0])[2]:.3f}" for c in frames.given)
        )
    if relative and fmt != "easy_handeye":
        lines.append(
            f"t_hand_pen_mm.z is written as t_hand_camera_mm.z + (z_pen - z_camera) = "
            f"0 + {frames.pen_minus_camera_z_mm:.3f} mm: only the difference is "
            "determined (from the hand's heights), so the pen sits right relative to "
            "the camera; give export --camera-z-mm to place both on the flange."
        )
    if not zeros:
        return lines
    lines.append(
        "NOT DETERMINED by the calibration data, written as 0 here (do not trust them; "
        "export --camera-z-mm or --pen-z-mm gives them):"
    )
    lines += [f"  {c}: {REASONS.get(c, 'not determined by the data')}" for c in zeros]
    return lines


def export_text(
    frames: Frames,
    fmt: str,
    *,
    names: FrameNames = FrameNames(),
    source: str = "",
    stage: int | None = None,
) -> str:
    """The calibration ``frames`` in format ``fmt`` (one of :data:`FORMATS`), as text.

    Args:
        frames: the fitted frames.
        fmt: ``json``, ``yaml``, ``urdf``, ``ros2``, ``opencv``, ``python`` or
            ``easy_handeye``.
        names: the link and frame names the file writes (:class:`FrameNames`: the flange
            link, the camera's optical frame, the pen tip's and the robot's base frame).
        source: where the frames came from (a file name), for the file's header.
        stage: the stage the file carries (default: the one the calibration deploys); URDF and
            ROS 2 and easy_handeye hold stage 1 only (:func:`carried_stage` raises
            :class:`StageError`).
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; known: {', '.join(FORMATS)}")
    stage = carried_stage(frames, fmt, stage)
    if fmt in ("json", "yaml"):
        doc = {**frames.to_dict(), "stage": stage, "stage_note": _stage_line(frames, stage)}
        if fmt == "json":
            return json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False) + "\n"
        import yaml

        head = "".join(f"# {line}\n" for line in _header_lines(frames, fmt, source, stage))
        return head + yaml.safe_dump(doc, sort_keys=False, allow_unicode=True, width=100)
    parent, camera, pen = names.parent_link, names.camera_frame, names.pen_frame
    if fmt == "urdf":
        return _urdf(frames, parent, camera, pen, source)
    if fmt == "ros2":
        return _ros2(frames, parent, camera, pen, source)
    if fmt == "opencv":
        return _opencv(frames, source, stage)
    if fmt == "python":
        return _python(frames, source, stage)
    if fmt == "easy_handeye":
        return _easy_handeye(frames, names.base_frame, parent, camera, source)
    raise ValueError(f"unknown format {fmt!r}; known: {', '.join(FORMATS)}")


def _frame_lines(parent: str, camera: str, pen: str) -> list[str]:
    return [
        f"{parent}: the hand (flange) frame: {AXES['hand']}.",
        "If your robot's flange link differs from it (a turn about z), add that fixed joint.",
        f"{camera}: {AXES['camera_optical']}.",
        f"{pen}: {AXES['pen_tip']}.",
    ]


def _urdf(frames: Frames, parent: str, camera: str, pen: str, source: str) -> str:
    cam, pen_t, _, _ = filled_translations_mm(frames)
    lines = [
        *_header_lines(frames, "urdf", source, 1),
        "ROS conventions: lengths in metres, angles in radians; rpy is fixed-axis roll, pitch,",
        "yaw: R = Rz(yaw)·Ry(pitch)·Rx(roll).",
        *_frame_lines(parent, camera, pen),
        *_undetermined_lines(frames, "urdf"),
    ]
    # An XML comment may not hold two hyphens in a row.
    comment = "\n".join(f"     {line}".rstrip() for line in _wrap(lines)).replace("--", "- -")

    def joint(child: str, xyz: list[float], rpy: tuple[float, float, float]) -> str:
        return (
            f'  <link name="{child}"/>\n'
            f'  <joint name="{parent}_to_{child}" type="fixed">\n'
            f'    <parent link="{parent}"/>\n'
            f'    <child link="{child}"/>\n'
            f'    <origin xyz="{" ".join(map(_num, xyz))}" rpy="{" ".join(map(_num, rpy))}"/>\n'
            "  </joint>\n"
        )

    return (
        '<?xml version="1.0"?>\n'
        f"<!--\n{comment}\n-->\n"
        '<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="handeye_jax_end_effector">\n'
        + joint(camera, _m(cam), rpy_radians(frames.R_hand_camera))
        + joint(pen, _m(pen_t), (0.0, 0.0, 0.0))
        + "</robot>\n"
    )


def static_transform_arguments(
    t_mm: np.ndarray, R: np.ndarray, parent: str, child: str
) -> list[str]:
    """The arguments of ``ros2 run tf2_ros static_transform_publisher`` (metres, x y z w)."""
    xyz = _m(t_mm)
    q = quaternion_xyzw(R)
    args = []
    for flag, value in zip(("x", "y", "z", "qx", "qy", "qz", "qw"), (*xyz, *q), strict=True):
        args += [f"--{flag}", _num(value)]
    return [*args, "--frame-id", parent, "--child-frame-id", child]


def _ros2(frames: Frames, parent: str, camera: str, pen: str, source: str) -> str:
    cam, pen_t, _, _ = filled_translations_mm(frames)
    transforms = {
        camera: static_transform_arguments(cam, frames.R_hand_camera, parent, camera),
        pen: static_transform_arguments(pen_t, np.eye(3), parent, pen),
    }
    lines = [
        *_header_lines(frames, "ros2", source, 1),
        "A ROS 2 launch file publishing the end-effector's static transforms with tf2_ros",
        "(named arguments: ROS 2 Humble or later).",
        "ROS conventions: metres; quaternions in the order x y z w.",
        *_frame_lines(parent, camera, pen),
        *_undetermined_lines(frames, "ros2"),
        "",
        "The same transforms from a shell:",
    ]
    commands = [
        "  " + shlex.join(["ros2", "run", "tf2_ros", "static_transform_publisher", *args])
        for args in transforms.values()
    ]
    nodes = "".join(
        "        Node(\n"
        '            package="tf2_ros",\n'
        '            executable="static_transform_publisher",\n'
        f'            name="static_tf_{child}",\n'
        f"            arguments={args!r},\n"
        "        ),\n"
        for child, args in transforms.items()
    )
    return (
        "".join(f"# {line}".rstrip() + "\n" for line in [*_wrap(lines), *commands])
        + "\nfrom launch import LaunchDescription\n"
        "from launch_ros.actions import Node\n\n\n"
        "def generate_launch_description():\n"
        "    return LaunchDescription([\n"
        f"{nodes}"
        "    ])\n"
    )


def _opencv(frames: Frames, source: str, stage: int) -> str:
    import cv2

    fs = cv2.FileStorage("export.yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    lines = [
        *_header_lines(frames, "opencv", source, stage),
        "R_cam2gripper, t_cam2gripper: as cv2.calibrateHandEye returns them: a point in the",
        "camera's optical frame to the gripper (hand, flange) frame, p_g = R·p_c + t; t in mm.",
        "R_tablet2base, t_tablet2base: the tablet in the robot base frame, mm.",
        "t_pentip2gripper: the pen tip (tool centre point) in the gripper frame, mm.",
        f"Frames: gripper = {AXES['hand']}. camera = {AXES['camera_optical']}.",
        f"tablet = {AXES['tablet']}.",
        "camera_matrix: [fx 0 cx; 0 fy cy; 0 0 1], px; distortion_coefficients: (k1 k2 p1 p2",
        "k3) as cv2.undistortPoints takes them (zeros: the pictures have no distortion).",
        "hand_angle: phi = zero_deg + sign * theta_h turns the gripper about its own z.",
        "stage2_A1, stage2_A2: (X mm, Y mm, theta deg, Sx, Sy) of eq. (24); stage2_centres_mm:",
        "their centres (rows). Hand command = A2(A1(x_bi) - x'), see the json export; with",
        "stage = 1 the hand command is x_bi - x' (R, t alone) and stage2_* are not used.",
        *_undetermined_lines(frames, "opencv"),
    ]
    for line in _wrap(lines):
        fs.writeComment(line)
    cam, pen, tab, _ = filled_translations_mm(frames)  # mm, unknowns as 0
    fx, fy, cx, cy = frames.camera_px
    fs.write("R_cam2gripper", frames.R_hand_camera)
    fs.write("t_cam2gripper", cam.reshape(3, 1))
    fs.write("translation_unit", "mm")
    fs.write("R_tablet2base", frames.R_base_tablet)
    fs.write("t_tablet2base", tab.reshape(3, 1))
    fs.write("t_pentip2gripper", pen.reshape(3, 1))
    fs.write("camera_matrix", np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]))
    fs.write("distortion_coefficients", np.array(frames.distortion or (0.0,) * 5).reshape(1, 5))
    fs.write("hand_angle_zero_deg", float(frames.hand_angle_zero_deg))
    fs.write("hand_angle_sign", int(frames.hand_angle_sign))
    fs.write("capture_position_mm", frames.capture_position_mm.reshape(3, 1))
    fs.write("capture_hand_angle_deg", float(frames.capture_hand_angle_deg))
    fs.write("stage2_A1", np.array(frames.A1.as_tuple()).reshape(5, 1))
    fs.write("stage2_A2", np.array(frames.A2.as_tuple()).reshape(5, 1))
    fs.write("stage2_centres_mm", frames.centres_mm)
    fs.write("stage", int(stage))
    fs.write("deploy_stage", int(frames.deploy_stage))
    fs.write("undetermined", " ".join(frames.undetermined))
    return fs.releaseAndGetString()


def _kernel_source() -> str:
    """The classes and functions of :mod:`handeye_jax.robot._npchain` and the lens's
    undistortion, as source (no docstring, no imports)."""
    source = inspect.getsource(_npchain)
    tree = ast.parse(source)
    parts = [ast.get_source_segment(source, node) for node in tree.body
             if isinstance(node, ast.FunctionDef | ast.ClassDef)]  # fmt: skip
    parts += [inspect.getsource(distort_px).rstrip(), inspect.getsource(undistort_px).rstrip()]
    return "\n\n\n".join(parts) + "\n"


def _py_vector(v: np.ndarray) -> str:
    return "np.array([" + ", ".join("np.nan" if math.isnan(x) else _num(x) for x in v) + "])"


def _py_matrix(R: np.ndarray) -> str:
    rows = ",\n    ".join("[" + ", ".join(_num(x) for x in row) + "]" for row in R)
    return f"np.array([\n    {rows},\n])"


def _python(frames: Frames, source: str, stage: int) -> str:
    f = frames
    names = {"base": "base", "hand": "hand", "camera_optical": "camera", "tablet": "tablet",
             "pen_tip": "pen tip"}  # fmt: skip
    axes = "\n".join(_wrap([f"    {names[k]}: {v}" for k, v in AXES.items()]))
    undetermined = "".join(
        line + "\n"
        for line in _wrap(
            [f"    {c}: {REASONS.get(c, 'not determined by the data')}" for c in f.undetermined]
        )
    )
    if undetermined:
        undetermined = "Not determined by the calibration data (NaN below, never read):\n\n" + (
            undetermined
        )
    header = "\n".join(_header_lines(f, "python", source, stage))
    return f'''r"""Hand commands for the robot PC: NumPy only, the fitted numbers inside.

{header}
Copy this one file beside your robot program; it needs NumPy and nothing else.

    import numpy as np
    import handeye_calibration as hc  # this file, saved as handeye_calibration.py

    hand_xy_mm = hc.hand_command(image_px, depth_mm, hand_angle_deg)  # (n, 2), base frame

Units: mm, deg, px. Frames (R_a_b maps frame b to frame a, p_a = R_a_b·p_b + t_a_b):

{axes}

{undetermined}"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

MODEL = {f.model!r}
# The camera's optical frame in the hand frame, and its origin there, mm.
R_HAND_CAMERA = {_py_matrix(f.R_hand_camera)}
T_HAND_CAMERA_MM = {_py_vector(f.t_hand_camera_mm)}
# The tablet in the base frame (not needed for hand commands), mm.
R_BASE_TABLET = {_py_matrix(f.R_base_tablet)}
T_BASE_TABLET_MM = {_py_vector(f.t_base_tablet_mm)}
# The pen tip (tool centre point) in the hand frame, mm.
T_HAND_PEN_MM = {_py_vector(f.t_hand_pen_mm)}
# Intrinsics (fx, fy, cx, cy), px, and the lens distortion: plumb_bob (k1, k2, p1, p2, k3), or
# None. Image points are undistorted with it before the chain.
CAMERA_PX = ({_num(f.fx_px)}, {_num(f.fy_px)}, {_num(f.cx_px)}, {_num(f.cy_px)})
DISTORTION = {None if f.distortion is None else "(" + ", ".join(map(_num, f.distortion)) + ")"}
# The controller's hand angle θh turns the hand about its own z by φ = ZERO + SIGN·θh, deg.
HAND_ANGLE_ZERO_DEG = {_num(f.hand_angle_zero_deg)}
HAND_ANGLE_SIGN = {f.hand_angle_sign}
# The hand pose when the calibration's picture was taken: position (mm), hand angle θh (deg).
CAPTURE_POSITION_MM = {_py_vector(f.capture_position_mm)}
CAPTURE_HAND_ANGLE_DEG = {_num(f.capture_hand_angle_deg)}
# Stage 2, eq. (24)-(25): (X mm, Y mm, θ deg, Sx, Sy) of A1 and A2, and their centres, mm.
A1 = ({", ".join(map(_num, f.A1.as_tuple()))})
A2 = ({", ".join(map(_num, f.A2.as_tuple()))})
CENTRES_MM = {_py_matrix(f.centres_mm)}
UNDETERMINED = {tuple(f.undetermined)!r}
# The stage hand_command uses by default: the one this file carries.
STAGE = {stage}
# z_pen − z_camera along the hand's z, mm: a command's height (None: the touches recorded none).
PEN_MINUS_CAMERA_Z_MM = {None if f.pen_minus_camera_z_mm is None else _num(f.pen_minus_camera_z_mm)}


def hand_command(
    image_px,
    depth_mm,
    hand_angle_deg,
    stage=STAGE,
    capture_position_mm=None,
    capture_hand_angle_deg=None,
    axes="xy",
):
    """Where to send the hand, (x, y) in mm in the robot base frame, shape (n, 2); with
    axes="xyz" (x, y, z), shape (n, 3), if the calibration determined heights.

    Args:
        image_px: (u, v) of each target in the picture, px, shape (n, 2).
        depth_mm: depth at each target, mm, shape (n,).
        hand_angle_deg: the hand angle θh to touch with, deg, (n,) or a scalar.
        stage: 2 (eq. 25, with the affine correction) or 1 (eq. 8); default: STAGE.
        capture_position_mm: the hand position when the picture was taken, mm, (3,) or
            (n, 3); default: the calibration's capture.
        capture_hand_angle_deg: the hand angle θh then, deg; default: the calibration's.
        axes: "xy", or "xyz" to add the hand's height.
    """
    if stage not in (1, 2):
        raise ValueError(f"stage must be 1 or 2 (got {{stage!r}})")
    if axes not in ("xy", "xyz") or (axes == "xyz" and PEN_MINUS_CAMERA_Z_MM is None):
        raise ValueError(f"axes must be 'xy' (or 'xyz' with heights; got {{axes!r}})")
    uv = undistort_px(np.asarray(image_px, dtype=np.float64).reshape(-1, 2), CAMERA_PX,
                      DISTORTION)
    n = uv.shape[0]
    depth = np.broadcast_to(np.asarray(depth_mm, dtype=np.float64), (n,))
    angle = np.broadcast_to(np.asarray(hand_angle_deg, dtype=np.float64), (n,))
    cap = CAPTURE_POSITION_MM if capture_position_mm is None else capture_position_mm
    cap_angle = CAPTURE_HAND_ANGLE_DEG if capture_hand_angle_deg is None else (
        np.asarray(capture_hand_angle_deg, dtype=np.float64)
    )
    cap = np.asarray(cap, dtype=np.float64)
    chain = Chain(CAMERA_PX, R_HAND_CAMERA, T_HAND_CAMERA_MM, T_HAND_PEN_MM, A1, A2, CENTRES_MM)
    xy = hand_command_xy(
        chain, uv, depth, HAND_ANGLE_ZERO_DEG + HAND_ANGLE_SIGN * angle, cap,
        HAND_ANGLE_ZERO_DEG + HAND_ANGLE_SIGN * cap_angle, stage=stage,
    )
    if axes == "xy":
        return xy
    z = image_to_base_z(chain, uv, depth, cap)
    return np.column_stack([xy, z + PEN_MINUS_CAMERA_Z_MM])


# The chain: handeye_jax.robot._npchain and the lens's undistortion, verbatim.


{_kernel_source()}'''


#: easy_handeye's calibration parameters, as its ``HandeyeCalibrationParameters`` takes them.
EASY_HANDEYE_PARAMETERS = ("namespace", "move_group_namespace", "move_group", "eye_on_hand",
                           "robot_base_frame", "robot_effector_frame", "tracking_base_frame",
                           "tracking_marker_frame")  # fmt: skip


def _easy_handeye(frames: Frames, base: str, parent: str, camera: str, source: str) -> str:
    import yaml

    cam, _, _, _ = filled_translations_mm(frames)
    x, y, z = _m(cam)
    qx, qy, qz, qw = quaternion_xyzw(frames.R_hand_camera)
    lines = [
        *_header_lines(frames, "easy_handeye", source, 1),
        "An eye-on-hand calibration in easy_handeye's file format (~/.ros/easy_handeye/NAME.yaml; "
        "HandeyeCalibration.from_file reads it): transformation is the camera's optical frame "
        f"({camera}) in the flange frame ({parent}), as tf publishes it from "
        "robot_effector_frame to tracking_base_frame: x y z in metres, the quaternion qx qy qz "
        "qw. The tracking marker is the tablet.",
        f"{parent}: the hand (flange) frame: {AXES['hand']}.",
        f"{camera}: {AXES['camera_optical']}.",
        "The pen tip, the tablet and the stage-2 correction are not part of this format: see the "
        "json or yaml export.",
        *_undetermined_lines(frames, "easy_handeye"),
    ]
    doc = {
        "parameters": dict(zip(EASY_HANDEYE_PARAMETERS, (
            "/handeye_jax_eye_on_hand/", "/", "manipulator", True, base, parent, camera,
            DEFAULT_TABLET_FRAME), strict=True)),
        "transformation": {"x": x, "y": y, "z": z, "qx": qx, "qy": qy, "qz": qz, "qw": qw},
    }  # fmt: skip
    head = "".join(f"# {line}".rstrip() + "\n" for line in _wrap(lines))
    return head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)


def check_parses(text: str, fmt: str) -> None:
    """Parse ``text`` as its format's reader would (a last guard before writing)."""
    if fmt == "json":
        json.loads(text)
    elif fmt in ("yaml", "easy_handeye"):
        import yaml

        yaml.safe_load(text)
    elif fmt in ("ros2", "python"):
        ast.parse(text)
    elif fmt == "urdf":
        import xml.etree.ElementTree as ET

        ET.fromstring(text)
    elif fmt == "opencv":
        import cv2

        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        if fs.getNode("R_cam2gripper").empty():
            raise ValueError("the OpenCV file lost R_cam2gripper")


__all__ = [
    "EASY_HANDEYE_PARAMETERS",
    "FORMATS",
    "RIGID_ONLY_FORMATS",
    "StageError",
    "carried_stage",
    "check_parses",
    "export_text",
    "quaternion_xyzw",
    "rpy_radians",
    "static_transform_arguments",
    "zero_filled",
]
