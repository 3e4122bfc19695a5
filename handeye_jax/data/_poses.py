"""Robot poses as the robot gives them: the tool flange's full pose in the base frame, turned
into the dataset's ``hand_position`` / ``hand_xy``, ``hand_z`` and ``hand_angle``. NumPy only.

**What a pose is.** The pose of the robot's tool flange frame in its base frame, ``T_base_tool``:
``p_base = R·p_tool + t`` (``t`` is the flange's origin in the base frame). That is what
``ros2 run tf2_ros tf2_echo base_link tool0`` prints (translation in metres, rotation as a
quaternion ``[x, y, z, w]``, also as roll-pitch-yaw and a 4×4 matrix) and what a controller
shows as its TCP or flange pose (in mm, with roll-pitch-yaw, a rotation vector or a quaternion).
The frame must have its z axis along the tool, pointing out of the flange: ROS-Industrial's and
Universal Robots' ``tool0``, ABB's ``tool0``, FANUC's faceplate. (A KUKA-style flange frame,
whose x axis is the tool axis, is refused as "not vertical": give ``tool0``.)

**The hand frame is that frame.** The toolkit's hand frame has z along the tool axis and turns
with the sixth axis; at a pose pointing straight down it is ``R_base_hand = Ry(180)·Rz(φ)``.
The pose's own frame is taken as the hand frame, so ``φ`` is read off the pose (the turn that
best fits ``R`` among those pointing down) and the hand angle is ``θ = sign·(φ − zero)`` under
the dataset's ``[hand_angle]`` convention (``zero = 0, sign = 1`` makes ``θ = φ``). The fixed
turn between ``tool0`` and the hand frame is thus the identity, by choice: any other turn about
the tool axis would be taken up by the camera's and the pen's fitted parameters (``γc`` and the
offsets ``xc, yc, xp, yp`` turn with it) and change no hand command, so it needs no measuring,
and every export's parent frame is ``tool0`` itself.

**Vertical.** The fit assumes the tool points straight down (eq. 1). A pose's *tilt* is the
angle between its tool axis and the base's −z. A tilt τ moves a point L below the flange by
``L·tan τ`` sideways, which no term of the fit sees: 0.26 mm per 100 mm of tool length at
0.15°, 1.75 mm at 1°. Tilts above :data:`TILT_WARN_DEG` are named in a warning; above
``max_tilt_deg`` (default :data:`MAX_TILT_DEG`) the pose is refused, naming its row.

**The CSV** (:func:`read_poses_csv`): one row per capture or touch of the dataset, header

* ``kind`` (``capture`` or ``touch``) and ``index`` (the capture's or touch's position in the
  dataset, from 0);
* the position: ``x_m,y_m,z_m`` (metres, as tf2 prints it) or ``x_mm,y_mm,z_mm``;
* one orientation: ``qx,qy,qz,qw`` (a unit quaternion; the columns are named, so their order
  is free: tf2's ``[x, y, z, w]`` and ABB's ``q1..q4 = w, x, y, z`` both fit);
  ``roll_deg,pitch_deg,yaw_deg`` or ``roll_rad,pitch_rad,yaw_rad`` (fixed axes X, Y, Z:
  ``R = Rz(yaw)·Ry(pitch)·Rx(roll)``, as ROS's RPY and URDF's ``rpy``; KUKA's A, B, C are
  yaw, pitch, roll; FANUC's W, P, R are roll, pitch, yaw);
  ``rotvec_x_rad,rotvec_y_rad,rotvec_z_rad`` (a rotation vector, axis times angle, as
  Universal Robots' Rx, Ry, Rz); or ``r00,r01,…,r22`` (the rotation matrix, row by row: the
  top-left 3×3 of the 4×4 ``T_base_tool``, whose last column is the position).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._core import MAX_TEXT_BYTES, InputError, csv_rows, read_text
from ._points import csv_number

#: Tilts above this (deg) are named in a warning.
TILT_WARN_DEG = 0.25
#: Tilts above this (deg) are refused unless a larger ``max_tilt_deg`` is given.
MAX_TILT_DEG = 1.0
#: Most rows a poses CSV may hold.
MAX_POSE_ROWS = 100_000
#: How far from 1 a quaternion's norm may be before it is refused as not a rotation.
QUATERNION_NORM_TOL = 1e-3
#: How far from orthonormal a rotation matrix read from a CSV may be (entries printed to
#: about 6 digits).
MATRIX_TOL = 1e-4
KINDS = ("capture", "touch")
POSITION_COLUMNS = {"m": ("x_m", "y_m", "z_m"), "mm": ("x_mm", "y_mm", "z_mm")}
ROTATION_COLUMNS = {
    "quaternion": ("qx", "qy", "qz", "qw"),
    "rpy_deg": ("roll_deg", "pitch_deg", "yaw_deg"),
    "rpy_rad": ("roll_rad", "pitch_rad", "yaw_rad"),
    "rotvec_rad": ("rotvec_x_rad", "rotvec_y_rad", "rotvec_z_rad"),
    "matrix": tuple(f"r{i}{j}" for i in range(3) for j in range(3)),
}
MM_PER = {"m": 1000.0, "mm": 1.0}
#: Largest position magnitude, mm (100 m).
MAX_POSITION_MM = 1e5


# -- rotations ---------------------------------------------------------------------------------


def rotation_from_quaternion(q_xyzw: Any) -> np.ndarray:
    """The rotation matrix of a unit quaternion given as ``(x, y, z, w)`` (ROS's order)."""
    x, y, z, w = np.asarray(q_xyzw, dtype=np.float64) / np.linalg.norm(q_xyzw)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def rotation_from_rpy(roll: float, pitch: float, yaw: float, degrees: bool = True) -> np.ndarray:
    """``Rz(yaw)·Ry(pitch)·Rx(roll)``: fixed-axis roll, pitch, yaw (ROS's RPY, URDF's rpy)."""
    r, p, y = (math.radians(a) if degrees else float(a) for a in (roll, pitch, yaw))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), \
        math.sin(y)  # fmt: skip
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])  # fmt: skip


def rotation_from_rotvec(rotvec_rad: Any) -> np.ndarray:
    """The rotation of a rotation vector (axis times angle, rad), by Rodrigues' formula."""
    v = np.asarray(rotvec_rad, dtype=np.float64)
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        return np.eye(3)
    k = v / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def quaternion_from_rotation(R: Any) -> np.ndarray:
    """The unit quaternion ``(x, y, z, w)`` of a rotation matrix, ``w >= 0`` (Shepperd)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.trace(R)
    cases = [t, R[0, 0], R[1, 1], R[2, 2]]
    i = int(np.argmax(cases))
    if i == 0:
        w = math.sqrt(1.0 + t) / 2.0
        q = [(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
             (R[1, 0] - R[0, 1]) / (4 * w), w]  # fmt: skip
    else:
        a, b, c = {1: (0, 1, 2), 2: (1, 2, 0), 3: (2, 0, 1)}[i]
        s = math.sqrt(1.0 + R[a, a] - R[b, b] - R[c, c]) * 2.0
        q = [0.0, 0.0, 0.0, (R[c, b] - R[b, c]) / s]
        q[a], q[b], q[c] = s / 4.0, (R[a, b] + R[b, a]) / s, (R[a, c] + R[c, a]) / s
    q = np.array(q)
    return -q if q[3] < 0 else q


# -- the hand pose of a tool pose --------------------------------------------------------------


def tilt_deg(R_base_tool: Any) -> float:
    """The angle between the tool axis (the frame's z) and straight down (base −z), deg."""
    R = np.asarray(R_base_tool, dtype=np.float64)
    return math.degrees(math.atan2(math.hypot(R[0, 2], R[1, 2]), -R[2, 2]))


def hand_phi_deg(R_base_tool: Any) -> float:
    """The hand's turn φ (deg) of the pointing-down rotation ``Ry(180)·Rz(φ)`` nearest
    ``R_base_tool`` (the one that maximises ``trace(Rᵀ·Ry(180)·Rz(φ))``)."""
    R = np.asarray(R_base_tool, dtype=np.float64)
    return math.degrees(math.atan2(R[0, 1] + R[1, 0], R[1, 1] - R[0, 0]))


def hand_angle_from_phi(phi_deg: float, zero_deg: float, sign: int, near_deg: float = 0.0):
    """The controller's hand angle θ (deg) with ``φ = zero + sign·θ``, taken within ±180° of
    ``near_deg`` (a row's previous value keeps a controller's 270° as 270°)."""
    theta = sign * (phi_deg - zero_deg)
    return near_deg + (theta - near_deg + 180.0) % 360.0 - 180.0


def tool_pose_of_hand(
    position_mm: Any, hand_angle_deg: float, zero_deg: float, sign: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(R_base_tool, t_base_tool_mm)`` of a hand pose pointing down: the flange pose to
    command for a capture or touch the dataset gives as ``hand_position`` and ``hand_angle``."""
    phi = math.radians(zero_deg + sign * hand_angle_deg)
    c, s = math.cos(phi), math.sin(phi)
    R = np.array([[-c, s, 0.0], [s, c, 0.0], [0.0, 0.0, -1.0]])  # Ry(180)·Rz(φ)
    return R, np.asarray(position_mm, dtype=np.float64).reshape(3)


# -- the CSV -----------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ToolPose:
    """One row of a poses CSV: a capture's or a touch's flange pose in the base frame.

    Attributes:
        kind: ``"capture"`` or ``"touch"``.
        index: which capture or touch of the dataset, from 0.
        R_base_tool: the flange's orientation, (3, 3).
        t_base_tool_mm: the flange's origin in the base frame, mm, (3,).
        line: the CSV line it came from, for messages.
    """

    kind: str
    index: int
    R_base_tool: np.ndarray
    t_base_tool_mm: np.ndarray
    line: int

    @property
    def tilt_deg(self) -> float:
        return tilt_deg(self.R_base_tool)

    @property
    def phi_deg(self) -> float:
        return hand_phi_deg(self.R_base_tool)


def _one_set(path: Path, header: list[str], sets: dict[str, tuple[str, ...]], what: str) -> str:
    """The name of the one column set of ``sets`` the header holds whole."""
    whole = [name for name, cols in sets.items() if all(c in header for c in cols)]
    if len(whole) == 1:
        return whole[0]
    options = "; ".join(",".join(c) for c in sets.values())
    if whole:
        raise InputError(path, "header", f"has more than one {what} ({' and '.join(whole)}); "
                         "keep one")  # fmt: skip
    partial = [c for cols in sets.values() for c in cols if c in header]
    got = f" (it has {', '.join(partial)} but not the rest of their set)" if partial else ""
    raise InputError(path, "header", f"needs one {what}: {options}{got}")


def _rotation(path: Path, where: str, kind: str, v: list[float]) -> np.ndarray:
    if kind == "quaternion":
        norm = math.sqrt(sum(x * x for x in v))
        if abs(norm - 1.0) > QUATERNION_NORM_TOL:
            raise InputError(path, where, f"quaternion (qx, qy, qz, qw) has norm {norm:.6g}, "
                             "not 1: not a rotation")  # fmt: skip
        return rotation_from_quaternion(v)
    if kind in ("rpy_deg", "rpy_rad"):
        return rotation_from_rpy(*v, degrees=kind == "rpy_deg")
    if kind == "rotvec_rad":
        return rotation_from_rotvec(v)
    R = np.array(v).reshape(3, 3)
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > MATRIX_TOL or np.linalg.det(R) < 0:
        what = f"off by {err:.2g}" if err > MATRIX_TOL else "a reflection (det < 0)"
        raise InputError(path, where, f"r00..r22 is not a rotation matrix ({what})")
    u, _, vt = np.linalg.svd(R)  # the nearest rotation to the printed digits
    return u @ vt


def read_poses_csv(path: str | Path) -> list[ToolPose]:
    """Read a poses CSV (see the module); :class:`InputError` names the file and the field.

    At most :data:`MAX_POSE_ROWS` rows; a capture or touch listed twice is refused.
    """
    path = Path(path)
    _, text = read_text(path, MAX_TEXT_BYTES)
    lines = list(itertools.islice(csv_rows(text, path), MAX_POSE_ROWS + 2))
    if not lines:
        raise InputError(path, "header", "file is empty; expected kind,index, a position and "
                         "an orientation")  # fmt: skip
    header = [h.strip() for h in lines[0]]
    twice = sorted({h for h in header if header.count(h) > 1})
    if twice:
        raise InputError(path, "header", f"column {twice[0]} appears more than once")
    for need in ("kind", "index"):
        if need not in header:
            raise InputError(path, "header", f"needs a column {need!r} (capture or touch, and "
                             "its index in the dataset)")  # fmt: skip
    unit = _one_set(path, header, POSITION_COLUMNS, "position")
    rot = _one_set(path, header, ROTATION_COLUMNS, "orientation")
    rows = lines[1:]
    if not rows:
        raise InputError(path, "rows", "no poses after the header")
    if len(rows) > MAX_POSE_ROWS:
        raise InputError(path, "rows", f"has more than {MAX_POSE_ROWS:,} poses, the most read")
    col = {h: j for j, h in enumerate(header)}
    limit = MAX_POSITION_MM / MM_PER[unit]
    out, seen = [], {}
    for n, row in enumerate(rows, start=2):
        where = f"line {n}"
        if len(row) != len(header):
            raise InputError(path, where, f"has {len(row)} fields, header has {len(header)}")
        kind = row[col["kind"]].strip()
        if kind not in KINDS:
            raise InputError(path, f"{where}.kind", f"must be capture or touch (got {kind!r:.40})")
        cell = row[col["index"]].strip()
        if not (cell.isascii() and cell.isdigit()) or len(cell) > 9:
            raise InputError(path, f"{where}.index", f"must be a whole number from 0 (got "
                             f"{cell!r:.40})")  # fmt: skip
        index = int(cell)
        if (kind, index) in seen:
            raise InputError(path, f"{where}.index", f"{kind} {index} is also on line "
                             f"{seen[kind, index]}")  # fmt: skip
        seen[kind, index] = n
        t = [csv_number(path, f"{where}.{c}", row[col[c]], limit) * MM_PER[unit]
             for c in POSITION_COLUMNS[unit]]  # fmt: skip
        bound = 1e3 if rot in ("rpy_rad", "rotvec_rad") else 1e5
        v = [csv_number(path, f"{where}.{c}", row[col[c]], bound) for c in ROTATION_COLUMNS[rot]]
        R = _rotation(path, f"{where}.{ROTATION_COLUMNS[rot][0]}", rot, v)
        out.append(ToolPose(kind, index, R, np.array(t), n))
    return out


def poses_csv_text(poses: list[ToolPose], unit: str = "m", digits: int = 9) -> str:
    """Poses as a CSV of ``kind,index,x,y,z,qx,qy,qz,qw`` (positions in ``unit``, ``"m"`` as
    tf2 prints them, or ``"mm"``): what :func:`read_poses_csv` reads."""
    head = ["kind", "index", *POSITION_COLUMNS[unit], *ROTATION_COLUMNS["quaternion"]]
    lines = [",".join(head)]
    for p in poses:
        xyz = p.t_base_tool_mm / MM_PER[unit]
        q = quaternion_from_rotation(p.R_base_tool)
        lines.append(",".join([p.kind, str(p.index), *(f"{v:.{digits}f}" for v in (*xyz, *q))]))
    return "\n".join(lines) + "\n"


__all__ = [
    "MAX_TILT_DEG",
    "TILT_WARN_DEG",
    "ToolPose",
    "hand_angle_from_phi",
    "hand_phi_deg",
    "poses_csv_text",
    "quaternion_from_rotation",
    "read_poses_csv",
    "rotation_from_quaternion",
    "rotation_from_rotvec",
    "rotation_from_rpy",
    "tilt_deg",
    "tool_pose_of_hand",
]
