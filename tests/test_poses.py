"""Robot poses as the robot gives them (issue 25): flange poses in any of the accepted forms
give the same hand poses, the rotations agree with scipy's, the tool's tilt is checked, and
``handeye-jax poses`` writes a dataset's hand poses from a CSV (bad input: one line naming
file and field, exit 2, nothing written)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from handeye_jax import PRESETS, draw_truth, load_dataset, simulate
from handeye_jax.cli import main
from handeye_jax.data import (
    ToolPose,
    apply_poses,
    hand_angle_from_phi,
    hand_phi_deg,
    poses_csv_text,
    quaternion_from_rotation,
    read_poses_csv,
    rotation_from_quaternion,
    rotation_from_rotvec,
    rotation_from_rpy,
    tilt_deg,
    tool_pose_of_hand,
)
from handeye_jax.twin import tool_poses

angles = st.floats(-179.0, 179.0)


@settings(max_examples=60, deadline=None)
@given(st.tuples(angles, st.floats(-89.0, 89.0), angles))
def test_rotations_agree_with_scipy(rpy):
    R = rotation_from_rpy(*rpy)
    # ROS's RPY: fixed axes x, y, z (R = Rz(yaw)·Ry(pitch)·Rx(roll)): scipy's extrinsic "xyz".
    assert np.allclose(R, Rotation.from_euler("xyz", rpy, degrees=True).as_matrix(), atol=1e-12)
    q = quaternion_from_rotation(R)  # x, y, z, w: scipy's scalar-last order too
    assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
    assert np.allclose(rotation_from_quaternion(q), R, atol=1e-12)
    assert np.allclose(Rotation.from_quat(q).as_matrix(), R, atol=1e-12)
    rv = Rotation.from_matrix(R).as_rotvec()
    assert np.allclose(rotation_from_rotvec(rv), R, atol=1e-10)


@settings(max_examples=60, deadline=None)
@given(st.floats(-720.0, 720.0), st.sampled_from([(90.0, -1), (0.0, 1), (90.0, 1), (0.0, -1)]),
       st.floats(0.0, 0.9), st.floats(0.0, 2 * math.pi))  # fmt: skip
def test_a_hand_pose_comes_back_from_its_flange_pose(theta, convention, tilt, axis):
    zero, sign = convention
    R, t = tool_pose_of_hand([300.0, -60.0, 290.0], theta, zero, sign)
    assert tilt_deg(R) < 1e-9
    tilted = rotation_from_rotvec(np.radians(tilt) * np.array([np.cos(axis), np.sin(axis), 0])) @ R
    assert abs(tilt_deg(tilted) - tilt) < 1e-9
    back = hand_angle_from_phi(hand_phi_deg(tilted), zero, sign, near_deg=theta)
    # A tilt moves the yaw read off the pose only to second order: < 1e-4 deg at 0.9 deg.
    assert abs(back - theta) < 1e-4


def _twin_dataset(tmp_path):
    twin = simulate(draw_truth(5, dot_px=2.0), PRESETS["none"], 5, exact=True, n_heldout=2,
                    captures=2)  # fmt: skip
    ds = twin.dataset
    path = tmp_path / "rig.toml"
    from handeye_jax import save_dataset

    save_dataset(ds, path)
    return ds, path


def _forms(poses: list[ToolPose]) -> dict[str, str]:
    """The same poses as a CSV in each accepted form."""
    rows = {"quaternion_m": poses_csv_text(poses, "m")}
    heads = {
        "rpy_deg_mm": "kind,index,x_mm,y_mm,z_mm,roll_deg,pitch_deg,yaw_deg",
        "rotvec_mm": "kind,index,x_mm,y_mm,z_mm,rotvec_x_rad,rotvec_y_rad,rotvec_z_rad",
        "matrix_m": "index,kind," + ",".join(f"r{i}{j}" for i in range(3) for j in range(3))
        + ",z_m,y_m,x_m",
        "wxyz_rpy_rad": "kind,index,x_m,y_m,z_m,roll_rad,pitch_rad,yaw_rad",
    }
    lines = {k: [h] for k, h in heads.items()}
    for p in poses:
        r = Rotation.from_matrix(p.R_base_tool)
        t = p.t_base_tool_mm
        f = lambda v: ",".join(f"{x:.12f}" for x in v)  # noqa: E731
        lines["rpy_deg_mm"].append(f"{p.kind},{p.index},{f(t)},{f(r.as_euler('xyz', True))}")
        lines["rotvec_mm"].append(f"{p.kind},{p.index},{f(t)},{f(r.as_rotvec())}")
        lines["matrix_m"].append(f"{p.index},{p.kind},{f(p.R_base_tool.ravel())},"
                                 f"{f(t[::-1] / 1000)}")  # fmt: skip
        lines["wxyz_rpy_rad"].append(f"{p.kind},{p.index},{f(t / 1000)},{f(r.as_euler('xyz'))}")
    rows |= {k: "\n".join(v) + "\n" for k, v in lines.items()}
    return rows


def test_every_form_gives_the_twins_hand_poses(tmp_path):
    ds, _ = _twin_dataset(tmp_path)
    poses = tool_poses(ds, tilt_sigma_deg=0.2, seed=3)
    scrambled = ds.replace(hand_xy_mm=ds.hand_xy_mm + 7.0, hand_angle_deg=ds.hand_angle_deg + 5)
    for name, text in _forms(poses).items():
        path = tmp_path / f"{name}.csv"
        path.write_text(text)
        got, report = apply_poses(scrambled, read_poses_csv(path))
        assert len(report.captures) == len(ds.captures) and len(report.touches) == ds.n_touches
        assert np.abs(got.hand_xy_mm - ds.hand_xy_mm).max() < 1e-6, name
        assert np.abs(got.hand_z_mm - ds.hand_z_mm).max() < 1e-6, name
        assert np.abs(got.hand_angle_deg - ds.hand_angle_deg).max() < 1e-6, name
        for a, b in zip(got.captures, ds.captures, strict=True):
            assert np.abs(a.hand_position_mm - b.hand_position_mm).max() < 1e-6
            assert abs(a.hand_angle_deg - b.hand_angle_deg) < 1e-6
        assert 0.0 < report.largest_tilt[2] < 1.0


def test_poses_command_updates_the_dataset_in_place(tmp_path, capsys):
    ds, path = _twin_dataset(tmp_path)
    scrambled = ds.replace(hand_xy_mm=ds.hand_xy_mm + 7.0)
    from handeye_jax import save_dataset

    save_dataset(scrambled, path)
    csv = tmp_path / "poses.csv"
    csv.write_text(poses_csv_text(tool_poses(ds)))
    assert main(["poses", str(path), str(csv)]) == 0
    out = capsys.readouterr().out
    assert "2 capture(s)" in out and f"{ds.n_touches} touch(es)" in out and "updated" in out
    assert np.abs(load_dataset(path).hand_xy_mm - ds.hand_xy_mm).max() < 1e-6
    assert len(list(tmp_path.glob("rig.toml.*.bak"))) == 1


BAD = [
    ("kind,index,x_m,y_m,z_m\ncapture,0,0.3,0,0.3\n", "header: needs one orientation"),
    ("kind,index,x_m,y_m,qx,qy,qz,qw\n", "header: needs one position"),
    ("kind,x_m,y_m,z_m,qx,qy,qz,qw\n", "header: needs a column 'index'"),
    ("kind,index,x_m,y_m,z_m,qx,qy,qz,qw,roll_deg,pitch_deg,yaw_deg\n",
     "more than one orientation"),
    ("kind,index,x_m,y_m,z_m,qx,qy,qz,qw\ncapture,0,0.3,0,0.3,0,1,0,0.5\n",
     "line 2.qx: quaternion (qx, qy, qz, qw) has norm 1.11803"),
    ("kind,index,x_m,y_m,z_m,qx,qy,qz,qw\ncapture,0,0.3,nan,0.3,0,1,0,0\n",
     "line 2.y_m: must be finite"),
    ("kind,index,x_m,y_m,z_m,qx,qy,qz,qw\ncamera,0,0.3,0,0.3,0,1,0,0\n",
     "line 2.kind: must be capture or touch"),
    ("kind,index,x_m,y_m,z_m,qx,qy,qz,qw\ncapture,-1,0.3,0,0.3,0,1,0,0\n",
     "line 2.index: must be a whole number"),
    ("kind,index,x_m,y_m,z_m,qx,qy,qz,qw\ncapture,7,0.3,0,0.3,0,1,0,0\n",
     "line 2.index: capture 7: the dataset has 2 captures"),
    ("kind,index,x_m,y_m,z_m,qx,qy,qz,qw\ntouch,0,0.3,0,0.3,0,1,0,0\ntouch,0,0.3,0,0.3,0,1,0,0\n",
     "line 3.index: touch 0 is also on line 2"),
    # z up: a frame whose z axis points into the robot, 180 deg from the tool pointing down
    ("kind,index,x_m,y_m,z_m,qx,qy,qz,qw\ntouch,1,0.3,0,0.3,0,0,0,1\n",
     "line 2: the tool of touch 1 is 180.00 deg from vertical"),
    ("kind,index,x_mm,y_mm,z_mm,roll_deg,pitch_deg,yaw_deg\ntouch,1,300,0,300,178,0,0\n",
     "line 2: the tool of touch 1 is 2.00 deg from vertical (at most 1;"),
    ("kind,index,x_m,y_m,z_m," + ",".join(f"r{i}{j}" for i in range(3) for j in range(3))
     + "\ncapture,0,0.3,0,0.3,1,0,0,0,1,0,0,0,2\n", "line 2.r00: r00..r22 is not a rotation"),
]  # fmt: skip


@pytest.mark.parametrize("text, why", BAD)
def test_bad_poses_are_one_line_naming_file_and_field(tmp_path, capsys, text, why):
    _, path = _twin_dataset(tmp_path)
    before = path.read_bytes()
    csv = tmp_path / "poses.csv"
    csv.write_text(text)
    assert main(["poses", str(path), str(csv)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and why in err and "poses.csv" in err, err
    assert path.read_bytes() == before and not list(tmp_path.glob("*.bak"))


def test_a_tilt_is_named_in_a_warning_and_max_tilt_widens(tmp_path, capsys):
    ds, path = _twin_dataset(tmp_path)
    poses = tool_poses(ds)
    p = poses[3]
    tilted = rotation_from_rotvec([np.radians(1.5), 0.0, 0.0]) @ p.R_base_tool
    poses[3] = ToolPose(p.kind, p.index, tilted, p.t_base_tool_mm, p.line)
    csv = tmp_path / "poses.csv"
    csv.write_text(poses_csv_text(poses))
    assert main(["poses", str(path), str(csv)]) == 2
    assert f"the tool of {p.kind} {p.index} is 1.50 deg from vertical" in capsys.readouterr().err
    assert main(["poses", str(path), str(csv), "--max-tilt-deg", "2"]) == 0
    captured = capsys.readouterr()
    assert f"warning: 1 of {len(poses)} poses tilted more than 0.25 deg" in captured.err
    assert f"{p.kind} {p.index} (1.50 deg)" in captured.err


def test_a_version_1_dataset_is_refused_with_the_way_out(tmp_path, capsys):
    from tests.common import PAPER

    csv = tmp_path / "poses.csv"
    csv.write_text("kind,index,x_m,y_m,z_m,qx,qy,qz,qw\ncapture,0,0.32,-0.07,0.29,0,1,0,0\n")
    assert main(["poses", str(PAPER), str(csv), "--out", str(tmp_path / "o.toml")]) == 2
    assert "is version 1: convert it first" in capsys.readouterr().err


def test_plan_writes_the_tool0_poses_the_poses_command_reads_back(tmp_path, capsys):
    ds, path = _twin_dataset(tmp_path)
    from handeye_jax import save_dataset

    save_dataset(ds.replace(captures=ds.captures[:1]), path)
    planned = tmp_path / "planned.csv"
    assert main(["plan", str(path), "--poses-csv", str(planned)]) == 0
    out = capsys.readouterr().out
    assert "tool0 in the base frame at [" in out and "quaternion (x y z w)" in out
    new = load_dataset(path)
    rows = read_poses_csv(planned)
    assert [(r.kind, r.index) for r in rows] == [("capture", k) for k in range(3)]
    got, report = apply_poses(new, rows)
    assert report.largest_tilt[2] < 1e-6
    for a, b in zip(got.captures, new.captures, strict=True):
        assert np.abs(a.hand_position_mm - b.hand_position_mm).max() < 1e-6
        assert abs(a.hand_angle_deg - b.hand_angle_deg) < 1e-6
