"""``handeye-jax export`` (issue 19, part 1): every format read back with its ecosystem's own
reader rebuilds a chain that gives the toolkit's hand commands; OpenCV's own hand-eye solver
agrees with the ``opencv`` export on which way T_hand_camera points."""

from __future__ import annotations

import ast
import dataclasses
import importlib.util
import json
import math
import shlex
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from frames_cases import TOL_MM, Case, cases, jax_reference, points, run_without_jax
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from handeye_jax import Frames, Predictor, compute_frames, draw_truth, save_result
from handeye_jax.calibration._result_frames import UNDETERMINED
from handeye_jax.cli import main
from handeye_jax.robot import (
    FORMATS,
    RIGID_ONLY_FORMATS,
    Affine,
    FrameNames,
    export_text,
    zero_filled,
)

NAMES = {"parent": "flange_link", "camera": "cam_optical", "pen": "pen_tcp"}
SUFFIX = {"json": ".json", "yaml": ".yaml", "urdf": ".urdf.xacro", "ros2": ".launch.py",
          "opencv": ".yml", "python": ".py", "easy_handeye": ".yaml"}  # fmt: skip


def _export(frames: Frames, fmt: str, folder: Path) -> Path:
    path = folder / f"export{SUFFIX[fmt]}"
    # URDF and ROS 2 hold stage 1 alone; they refuse to stand for a stage-2 deployment.
    stage = 1 if fmt in RIGID_ONLY_FORMATS else None
    names = FrameNames(NAMES["parent"], NAMES["camera"], NAMES["pen"])
    text = export_text(frames, fmt, names=names, source="drawn.json", stage=stage)
    path.write_text(text, encoding="utf-8")
    return path


def _nan_if(frames: Frames, name: str, v) -> np.ndarray:
    """A translation read from a file that writes 0 for unknowns: NaN where the frames say
    undetermined (and check the file wrote exactly 0 there)."""
    out = np.array(v, dtype=float)
    for i, axis in enumerate("xyz"):
        if f"{name}.{axis}" in frames.undetermined:
            assert out[i] == 0.0
            out[i] = np.nan
    return out


def _with(frames: Frames, R_hand_camera, t_hand_camera_m, t_hand_pen_m) -> Frames:
    return dataclasses.replace(
        frames, R_hand_camera=R_hand_camera,
        t_hand_camera_mm=_nan_if(frames, "t_hand_camera_mm", np.array(t_hand_camera_m) * 1000),
        t_hand_pen_mm=_nan_if(frames, "t_hand_pen_mm", np.array(t_hand_pen_m) * 1000),
    )  # fmt: skip


def read_urdf(path: Path, frames: Frames) -> Frames:
    """An XML parser's reading: the two fixed joints replace the camera mount and the pen."""
    root = ET.parse(path).getroot()
    joints = {j.find("child").get("link"): j for j in root.iter("joint")}
    assert set(joints) == {NAMES["camera"], NAMES["pen"]}
    assert {link.get("name") for link in root.iter("link")} == set(joints)
    origin = {}
    for child, j in joints.items():
        assert j.get("type") == "fixed" and j.find("parent").get("link") == NAMES["parent"]
        o = j.find("origin")
        origin[child] = ([float(x) for x in o.get("xyz").split()],
                         [float(x) for x in o.get("rpy").split()])  # fmt: skip
    xyz, rpy = origin[NAMES["camera"]]
    # URDF's rpy: fixed axes x, y, z, i.e. R = Rz(yaw)·Ry(pitch)·Rx(roll); scipy's "xyz"
    R = Rotation.from_euler("xyz", rpy).as_matrix()
    pen_xyz, pen_rpy = origin[NAMES["pen"]]
    assert pen_rpy == [0.0, 0.0, 0.0]
    return _with(frames, R, xyz, pen_xyz)


def read_ros2(path: Path, frames: Frames) -> Frames:
    """The launch file parsed as Python (ast), the shell commands in its header with shlex."""
    text = path.read_text()
    tree = ast.parse(text)
    nodes = [n for n in ast.walk(tree)
             if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "Node"]  # fmt: skip
    transforms = {}
    for node in nodes:
        kw = {k.arg: ast.literal_eval(k.value) for k in node.keywords}
        assert (kw["package"], kw["executable"]) == ("tf2_ros", "static_transform_publisher")
        args = dict(zip(kw["arguments"][::2], kw["arguments"][1::2], strict=True))
        assert args["--frame-id"] == NAMES["parent"]
        transforms[args["--child-frame-id"]] = args
    commands = [shlex.split(line.lstrip("# ")) for line in text.splitlines()
                if line.startswith("#   ros2 run tf2_ros")]  # fmt: skip
    assert [dict(zip(c[4::2], c[5::2], strict=True)) for c in commands] == list(transforms.values())

    def pose(args):
        t = [float(args[f"--{k}"]) for k in "xyz"]
        q = [float(args[f"--{k}"]) for k in ("qx", "qy", "qz", "qw")]
        return Rotation.from_quat(q).as_matrix(), t  # scipy's order is x y z w, as ROS's

    R, t = pose(transforms[NAMES["camera"]])
    R_pen, t_pen = pose(transforms[NAMES["pen"]])
    np.testing.assert_array_equal(R_pen, np.eye(3))
    return _with(frames, R, t, t_pen)


def read_opencv(path: Path, frames: Frames) -> Frames:
    """``cv2.FileStorage``'s reading; every number of the chain comes from the file."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    mat = lambda k: fs.getNode(k).mat()  # noqa: E731
    real = lambda k: fs.getNode(k).real()  # noqa: E731
    assert fs.getNode("translation_unit").string() == "mm"
    undetermined = tuple(fs.getNode("undetermined").string().split())
    assert undetermined == frames.undetermined
    K = mat("camera_matrix")
    A1, A2 = (Affine(*mat(k).ravel()) for k in ("stage2_A1", "stage2_A2"))
    out = Frames(
        R_hand_camera=mat("R_cam2gripper"),
        t_hand_camera_mm=_nan_if(frames, "t_hand_camera_mm", mat("t_cam2gripper").ravel()),
        R_base_tablet=mat("R_tablet2base"),
        t_base_tablet_mm=_nan_if(frames, "t_base_tablet_mm", mat("t_tablet2base").ravel()),
        t_hand_pen_mm=_nan_if(frames, "t_hand_pen_mm", mat("t_pentip2gripper").ravel()),
        fx_px=K[0, 0], fy_px=K[1, 1], cx_px=K[0, 2], cy_px=K[1, 2],
        hand_angle_zero_deg=real("hand_angle_zero_deg"),
        hand_angle_sign=int(real("hand_angle_sign")),
        capture_position_mm=mat("capture_position_mm").ravel(),
        capture_hand_angle_deg=real("capture_hand_angle_deg"),
        A1=A1, A2=A2, centres_mm=mat("stage2_centres_mm"), undetermined=undetermined,
    )  # fmt: skip
    fs.release()
    return out


def read_python(path: Path, frames: Frames):
    """Importing the generated module; its ``hand_command`` is the chain."""
    spec = importlib.util.spec_from_file_location(f"generated_{abs(hash(path))}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.UNDETERMINED == frames.undetermined
    return module


def read_easy_handeye(path: Path, frames: Frames) -> Frames:
    """PyYAML's reading of easy_handeye's file: the camera mount (x y z m, qx qy qz qw); the
    format holds nothing else, so the rest of the chain is the frames'."""
    doc = yaml.safe_load(path.read_text())
    assert doc["parameters"]["robot_effector_frame"] == NAMES["parent"]
    assert doc["parameters"]["tracking_base_frame"] == NAMES["camera"]
    tr = doc["transformation"]
    R = Rotation.from_quat([tr["qx"], tr["qy"], tr["qz"], tr["qw"]]).as_matrix()
    return _with(frames, R, [tr["x"], tr["y"], tr["z"]], np.nan_to_num(frames.t_hand_pen_mm) / 1e3)


READERS = {
    "json": lambda p, f: Frames.from_dict(json.loads(p.read_text()), p),
    "yaml": lambda p, f: Frames.from_dict(yaml.safe_load(p.read_text()), p),
    "urdf": read_urdf,
    "ros2": read_ros2,
    "opencv": read_opencv,
    "python": read_python,
    "easy_handeye": read_easy_handeye,
}


def hand_commands(path: Path, fmt: str, frames: Frames, pts, stage: int) -> np.ndarray:
    """The hand commands of the chain rebuilt from an exported file."""
    rebuilt = READERS[fmt](path, frames)
    if fmt == "python":
        return rebuilt.hand_command(*pts, stage=stage)
    return Predictor.from_frames(rebuilt).hand_command(*pts, stage=stage)


@pytest.mark.parametrize("fmt", FORMATS)
@settings(max_examples=8, deadline=None)
@given(case=cases(), pts=points(), stage=st.sampled_from([1, 2]))
def test_every_format_round_trips_to_the_toolkits_hand_commands(tmp_path_factory, fmt, case,
                                                                 pts, stage):  # fmt: skip
    frames = case.frames()
    path = _export(frames, fmt, tmp_path_factory.mktemp(fmt))
    got = hand_commands(path, fmt, frames, pts, stage)
    np.testing.assert_allclose(got, jax_reference(case, *pts, stage), rtol=0, atol=TOL_MM)


@settings(max_examples=8, deadline=None)
@given(case=cases(), dz=st.tuples(*[st.floats(-80, 80)] * 3))
def test_known_components_are_exported_not_zeroed(tmp_path_factory, case, dz):
    """A twin's truth (or a measured height) is written as a number everywhere."""
    known = dict(zip(UNDETERMINED, dz, strict=True))
    frames = case.frames(**known)
    assert frames.undetermined == ()
    folder = tmp_path_factory.mktemp("known")
    urdf = read_urdf(_export(frames, "urdf", folder), frames)
    ros2 = read_ros2(_export(frames, "ros2", folder), frames)
    ocv = read_opencv(_export(frames, "opencv", folder), frames)
    for rebuilt in (urdf, ros2, ocv):
        np.testing.assert_allclose(rebuilt.t_hand_camera_mm, frames.t_hand_camera_mm, atol=1e-12)
        np.testing.assert_allclose(rebuilt.t_hand_pen_mm, frames.t_hand_pen_mm, atol=1e-12)
        np.testing.assert_allclose(rebuilt.R_hand_camera, frames.R_hand_camera, atol=1e-14)
    np.testing.assert_array_equal(ocv.t_base_tablet_mm, frames.t_base_tablet_mm)


def _paper_case() -> Case:
    params = {"xc": -2.05, "yc": 34.09, "alpha_c": 0.49, "beta_c": 0.48, "gamma_c": -0.73,
              "xt": 193.33, "yt": 31.62, "alpha_t": 1.5, "beta_t": -11.9, "gamma_t": -1.2,
              "xp": -0.46, "yp": -22.27}  # fmt: skip
    affine = {"X1": -0.1, "Y1": 0.003, "theta1": 0.03, "Sx1": 0.998, "Sy1": 1.02,
              "X2": 0.06, "Y2": -0.11, "theta2": -0.02, "Sx2": 1.017, "Sy2": 0.988}  # fmt: skip
    return Case("htm", params, affine, (617.7, 617.7, 316.5, 242.3), (320.0, -70.0, 290.0),
                90.0, -1, ((326.5, -37.9), (325.9, -15.6)))  # fmt: skip


@pytest.fixture(scope="module")
def case_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("export") / "paper.result.json"
    save_result(_paper_case().result(), path)
    return path


PTS = (np.array([[119.0, 105.0], [338.0, 244.0], [554.0, 381.0]]),
       np.array([168.2, 169.2, 168.9]), np.array([0.0, 90.0, 180.0]))  # fmt: skip


@pytest.mark.parametrize("fmt", FORMATS)
def test_cli_export_writes_each_format_and_warns_of_zeros(tmp_path, case_file, capsys, fmt):
    out = tmp_path / f"out{SUFFIX[fmt]}"
    args = ["export", str(case_file), "--format", fmt, "--out", str(out),
            "--parent-link", NAMES["parent"], "--camera-frame", NAMES["camera"],
            "--pen-frame", NAMES["pen"]]  # fmt: skip
    if fmt in RIGID_ONLY_FORMATS:  # the case deploys stage 2, which these cannot hold
        assert main(args) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--format" in err and "--stage 1" in err
        assert not out.exists()
        args.insert(4, "--stage=1")
    assert main(args) == 0
    io = capsys.readouterr()
    frames = Predictor.from_result(case_file).frames
    zeros = zero_filled(frames, fmt)
    if zeros:  # one line naming them, and the file says so beside the numbers
        assert io.err.startswith(f"handeye-jax: warning: {', '.join(zeros)} not determined by "
                                 f"the data: written as 0 in the {fmt} file, which says so; give "
                                 "--camera-z-mm")  # fmt: skip
        assert io.err.count("\n") == 1
        text = out.read_text()
        assert "NOT DETERMINED" in text and all(c in text for c in zeros)
    else:
        assert io.err == ""
    want = Predictor.from_frames(frames).hand_command(*PTS)
    np.testing.assert_allclose(hand_commands(out, fmt, frames, PTS, 2), want, atol=TOL_MM)
    # without --out, the same text goes to standard output
    assert main(args[:-8] + args[-6:]) == 0
    assert capsys.readouterr().out == out.read_text()


def test_json_and_yaml_say_null_never_zero(case_file, tmp_path, capsys):
    for fmt, load in (("json", json.loads), ("yaml", yaml.safe_load)):
        assert main(["export", str(case_file), "--format", fmt]) == 0
        doc = load(capsys.readouterr().out)
        for key, vec in (("T_hand_camera", "t"), ("T_base_tablet", "t"),
                         ("pen_tip", "t_hand_pen")):  # fmt: skip
            assert doc[key][vec]["mm"][2] is None and doc[key][vec]["determined"][2] is False
            assert all(isinstance(x, float) for x in doc[key][vec]["mm"][:2])
        listed = {u["component"]: u["reason"] for u in doc["undetermined"]}
        assert set(listed) == set(UNDETERMINED) and all(len(r) > 20 for r in listed.values())
        assert doc["units"] == {"length": "mm", "angle": "deg", "image": "px"}
        assert set(doc["axes"]) == {"base", "hand", "camera_optical", "tablet", "pen_tip"}
        assert doc["hand_angle"]["zero_deg"] == 90.0 and doc["hand_angle"]["sign"] == -1


def test_generated_module_runs_without_jax(case_file, tmp_path):
    path = tmp_path / "handeye_calibration.py"
    assert main(["export", str(case_file), "--format", "python", "--out", str(path)]) == 0
    p = run_without_jax(
        """
        import importlib.util, numpy as np
        spec = importlib.util.spec_from_file_location("hc", sys.argv[1])
        hc = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(hc)
        pts = json.loads(sys.argv[2])
        print(json.dumps(hc.hand_command(np.array(pts[0]), pts[1], pts[2]).tolist()))
        """,
        str(path), json.dumps([a.tolist() for a in PTS]),
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    want = Predictor.from_result(case_file).hand_command(*PTS)
    np.testing.assert_array_equal(json.loads(p.stdout), want)


def test_cli_export_refuses_bad_names_and_edited_frames(case_file, tmp_path, capsys):
    out = tmp_path / "x.urdf"
    with pytest.raises(SystemExit) as e:
        main(["export", str(case_file), "--format", "urdf", "--parent-link", 'a"/><x'])
    assert e.value.code == 2
    assert "not a valid link or frame name" in capsys.readouterr().err
    code = main(["export", str(case_file), "--format", "urdf", "--camera-frame", "tool0",
                 "--out", str(out)])  # fmt: skip
    assert code == 2 and not out.exists()
    doc = json.loads(case_file.read_text())
    doc["frames"]["T_hand_camera"]["R"] = np.eye(3).tolist()
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(["export", str(edited), "--format", "urdf", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"handeye-jax: error: {edited}: frames: disagrees") and not out.exists()
    del doc["frames"]  # an older result: exported from its parameters
    edited.write_text(json.dumps(doc))
    assert main(["export", str(edited), "--format", "json", "--out", str(out)]) == 0
    again = Frames.from_dict(json.loads(out.read_text()))
    np.testing.assert_array_equal(again.R_hand_camera, Predictor.from_result(case_file)
                                  .frames.R_hand_camera)  # fmt: skip


def test_frame_names_default_to_ros_names_and_refuse_bad_or_shared_ones():
    assert FrameNames() == FrameNames("tool0", "camera_optical_frame", "pen_tip", "base_link")
    for field, bad in (("parent_link", 'a"/><x'), ("camera_frame", "1cam"), ("pen_frame", ""),
                       ("base_frame", "base link")):  # fmt: skip
        with pytest.raises(ValueError, match=rf"^{field}: not a valid link or frame name"):
            FrameNames(**{field: bad})
    with pytest.raises(ValueError, match=r"^parent_link, camera_frame, pen_frame: need three"):
        FrameNames(camera_frame="tool0")
    FrameNames(base_frame="tool0")  # the base frame is in no URDF or ROS 2 file with them
    urdf = export_text(_paper_case().frames(), "urdf", names=FrameNames(pen_frame="tcp"),
                       stage=1)  # fmt: skip
    assert [j.find("child").get("link") for j in ET.fromstring(urdf).iter("joint")] == [
        "camera_optical_frame", "tcp"]  # fmt: skip


def test_a_hostile_source_name_cannot_break_out_of_a_comment_or_string():
    frames = _paper_case().frames()
    source = 'x"""\n-->\nimport os\n#\r<!--'
    for fmt in ("urdf", "ros2", "python", "yaml", "opencv"):
        text = export_text(frames, fmt, source=source,
                           stage=1 if fmt in RIGID_ONLY_FORMATS else None)  # fmt: skip
        if fmt == "urdf":
            assert len(list(ET.fromstring(text).iter("joint"))) == 2
        elif fmt in ("ros2", "python"):
            imported = [a.name for n in ast.walk(ast.parse(text))
                        if isinstance(n, ast.Import | ast.ImportFrom) for a in n.names]  # fmt: skip
            assert "os" not in imported and imported  # the file's own imports are there
        elif fmt == "yaml":
            assert set(yaml.safe_load(text)) == set(frames.to_dict()) | {"stage", "stage_note"}
        else:
            fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
            assert fs.getNode("R_cam2gripper").mat().shape == (3, 3)


# -- OpenCV's own solver -------------------------------------------------------------------


def _T(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


@pytest.mark.parametrize("seed", [3])
def test_opencv_calibrate_hand_eye_matches_our_export_of_a_twins_truth(tmp_path, seed):
    """Noise-free motion pairs from a twin's true T_hand_camera: OpenCV's R_cam2gripper and
    t_cam2gripper equal our ``opencv`` export to 1e-6 (so the direction is OpenCV's)."""
    assert hasattr(cv2, "calibrateHandEye"), (
        f"OpenCV {cv2.__version__}'s Python bindings lack calibrateHandEye (opencv/opencv#29565); "
        "pyproject.toml excludes that release: reinstall with pip install -e '.[test]'"
    )
    truth = draw_truth(seed)
    frames = compute_frames(
        truth.htm(), truth.rig(),
        known={"t_hand_camera_mm.z": truth.camera_z_mm,
               "t_base_tablet_mm.z": truth.tablet_height_mm},
    )  # fmt: skip
    # These frames are the twin's: they map its landmarks, seen by its camera, onto its tablet.
    tablet_mm = truth.landmarks_tablet_px * truth.mm_per_tablet_px
    on_tablet = tablet_mm @ frames.R_base_tablet[:, :2].T + frames.t_base_tablet_mm
    R_bh = np.diag([-1.0, 1.0, -1.0])  # the capture: φ = 0
    seen = (truth.camera_points(truth.landmarks_tablet_px) @ frames.R_hand_camera.T
            + frames.t_hand_camera_mm) @ R_bh.T + frames.capture_position_mm  # fmt: skip
    np.testing.assert_allclose(seen, on_tablet, atol=1e-9)

    path = tmp_path / "truth.yml"
    path.write_text(export_text(frames, "opencv"))
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    R_export, t_export = fs.getNode("R_cam2gripper").mat(), fs.getNode("t_cam2gripper").mat()
    X = _T(frames.R_hand_camera, frames.t_hand_camera_mm)  # T_gripper_camera, the truth
    rng = np.random.default_rng(seed)
    T_base_target = _T(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-300, 300, 3))
    R_g2b, t_g2b, R_t2c, t_t2c = [], [], [], []
    for _ in range(12):
        T_base_gripper = _T(Rotation.random(random_state=rng).as_matrix(),
                            rng.uniform(-500, 500, 3))  # fmt: skip
        T_cam_target = np.linalg.inv(T_base_gripper @ X) @ T_base_target
        R_g2b.append(T_base_gripper[:3, :3])
        t_g2b.append(T_base_gripper[:3, 3:])
        R_t2c.append(T_cam_target[:3, :3])
        t_t2c.append(T_cam_target[:3, 3:])
    for method in (cv2.CALIB_HAND_EYE_TSAI, cv2.CALIB_HAND_EYE_PARK, cv2.CALIB_HAND_EYE_HORAUD,
                   cv2.CALIB_HAND_EYE_ANDREFF, cv2.CALIB_HAND_EYE_DANIILIDIS):  # fmt: skip
        R, t = cv2.calibrateHandEye(R_g2b, t_g2b, R_t2c, t_t2c, method=method)
        np.testing.assert_allclose(R, R_export, atol=1e-6, err_msg=f"method {method}")
        np.testing.assert_allclose(t, t_export, atol=1e-6, err_msg=f"method {method}")
    assert not math.isclose(float(t_export[2, 0]), 0.0)  # the twin's camera height is there
