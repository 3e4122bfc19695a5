"""Exports for the robot (issue 25): the z the data leaves open is given (``--camera-z-mm``)
or written as the determined ``z_pen − z_camera``, never a silent 0; the easy_handeye YAML is
read back as easy_handeye reads it and its transform rebuilt with ``transformations`` (the
library ROS's ``tf.transformations`` is), against the result's frames."""

from __future__ import annotations

import inspect
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest
import transformations
import yaml

from handeye_jax import PRESETS, calibrate, draw_truth, save_result, simulate
from handeye_jax.cli import main
from handeye_jax.robot import EASY_HANDEYE_PARAMETERS, export_text, with_heights
from tests.common import EXACT_RESTARTS, FAST_SETTINGS


class HandeyeCalibrationParameters:
    """easy_handeye's own class's signature (``handeye_calibration.py``): ``from_dict`` calls
    it with the file's ``parameters`` as keyword arguments, so they must be exactly these."""

    def __init__(self, namespace, move_group_namespace="/", move_group="manipulator",
                 eye_on_hand=None, robot_base_frame=None, robot_effector_frame=None,
                 tracking_base_frame=None, tracking_marker_frame=None):  # fmt: skip
        self.__dict__.update(locals())


@pytest.fixture(scope="module")
def heights_result(tmp_path_factory):
    """A noise-free three-capture twin's calibration: its touches recorded hand heights."""
    truth = draw_truth(6, dot_px=2.0)
    twin = simulate(truth, PRESETS["none"], 6, exact=True, n_heldout=2, captures=3)
    r = calibrate(twin.dataset, replace(FAST_SETTINGS, restarts=EXACT_RESTARTS))
    path = tmp_path_factory.mktemp("heights") / "r.json"
    save_result(r, path)
    return truth, r, path


def _urdf_z(text: str) -> dict[str, float]:
    root = ET.fromstring(text)
    return {j.find("child").get("link"): float(j.find("origin").get("xyz").split()[2])
            for j in root.iter("joint")}  # fmt: skip


def test_camera_z_gives_the_pen_z_by_the_determined_difference(heights_result, tmp_path, capsys):
    truth, r, path = heights_result
    d = r.frames().pen_minus_camera_z_mm
    assert abs(d - (truth.pen_z_mm - truth.camera_z_mm)) < 1e-6  # the twin's truth
    out = tmp_path / "ee.urdf.xacro"
    assert main(["export", str(path), "--format", "urdf", "--camera-z-mm", "31.5",
                 "--out", str(out)]) == 0  # fmt: skip
    assert "warning" not in capsys.readouterr().err
    z = _urdf_z(out.read_text())
    assert z["camera_optical_frame"] == pytest.approx(0.0315, abs=1e-12)
    assert z["pen_tip"] == pytest.approx((31.5 + d) / 1000, abs=1e-12)
    assert "GIVEN by the user" in out.read_text()
    # The pen's z instead gives the camera's; both at once contradict the data: refused.
    frames = with_heights(r.frames(), pen_z_mm=100.0)
    assert frames.t_hand_camera_mm[2] == pytest.approx(100.0 - d)
    assert frames.given == ("t_hand_camera_mm.z", "t_hand_pen_mm.z")
    assert main(["export", str(path), "--format", "urdf", "--camera-z-mm", "30",
                 "--pen-z-mm", "40"]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "give the camera's z or the pen's, not both" in err


def test_without_a_given_z_the_pen_sits_at_the_determined_difference(heights_result, capsys):
    _, r, path = heights_result
    d = r.frames().pen_minus_camera_z_mm
    assert main(["export", str(path), "--format", "urdf"]) == 0
    captured = capsys.readouterr()
    z = _urdf_z(captured.out)
    assert z["camera_optical_frame"] == 0.0 and z["pen_tip"] == pytest.approx(d / 1000)
    assert "only the difference is" in " ".join(captured.out.split())
    assert "warning: t_hand_camera_mm.z not determined" in captured.err
    assert "--camera-z-mm" in captured.err


def test_without_heights_camera_z_fills_only_the_camera(paper_result_file, capsys):
    # The paper's ML fit deploys stage 2: URDF carries stage 1's frames when asked.
    assert main(["export", str(paper_result_file), "--format", "urdf", "--stage", "1",
                 "--camera-z-mm", "12"]) == 0  # fmt: skip
    captured = capsys.readouterr()
    z = _urdf_z(captured.out)
    assert z["camera_optical_frame"] == pytest.approx(0.012) and z["pen_tip"] == 0.0
    assert "warning: t_hand_pen_mm.z not determined" in captured.err


def test_easy_handeye_yaml_reads_back_as_easy_handeye_reads_it(heights_result, tmp_path):
    _, r, path = heights_result
    out = tmp_path / "eih.yaml"
    assert main(["export", str(path), "--format", "easy_handeye", "--camera-z-mm", "25",
                 "--base-frame", "world", "--out", str(out)]) == 0  # fmt: skip
    doc = yaml.safe_load(out.read_text())  # easy_handeye: yaml.load of the file
    assert set(doc) == {"parameters", "transformation"}
    params = HandeyeCalibrationParameters(**doc["parameters"])
    assert tuple(inspect.signature(HandeyeCalibrationParameters).parameters) == \
        EASY_HANDEYE_PARAMETERS  # fmt: skip
    assert params.eye_on_hand is True
    assert (params.robot_base_frame, params.robot_effector_frame, params.tracking_base_frame) == \
        ("world", "tool0", "camera_optical_frame")  # fmt: skip
    tr = doc["transformation"]
    T = transformations.concatenate_matrices(
        transformations.translation_matrix([tr["x"], tr["y"], tr["z"]]),
        transformations.quaternion_matrix([tr["qw"], tr["qx"], tr["qy"], tr["qz"]]),
    )  # this library orders quaternions w, x, y, z; the file (as tf) x, y, z, w
    f = with_heights(r.frames(), camera_z_mm=25.0)
    assert np.abs(T[:3, :3] - f.R_hand_camera).max() < 1e-12
    assert np.abs(T[:3, 3] * 1000 - f.t_hand_camera_mm).max() < 1e-9
    # A camera point mapped by the file's transform lands where the frames put it, mm.
    p_cam = np.array([10.0, -20.0, 170.0, 1000.0]) / 1000
    assert np.abs((T @ p_cam)[:3] * 1000 - (f.R_hand_camera @ p_cam[:3] * 1000
                                             + f.t_hand_camera_mm)).max() < 1e-9


@pytest.mark.parametrize("which", ["paper", "heights"])
def test_easy_handeye_zero_fills_with_a_comment_when_z_is_not_given(paper_result, heights_result,
                                                                    which):
    r = paper_result if which == "paper" else heights_result[1]
    text = export_text(r.frames(), "easy_handeye", stage=1)  # rigid: stage 1's frames
    assert yaml.safe_load(text)["transformation"]["z"] == 0.0
    assert "NOT DETERMINED" in text and "t_hand_camera_mm.z" in text
