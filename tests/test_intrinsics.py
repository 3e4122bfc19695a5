"""Intrinsics as the camera's tools write them (issue 25): ROS camera_info (the calibration
file and a topic echo), OpenCV FileStorage YAML and XML (written by OpenCV itself) and a
RealSense-style JSON all give the same [camera]; ``handeye-jax intrinsics`` sets it; bad
files are one line naming the file and field. And ``detect`` reads depth in 0.1 mm units."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest
import yaml

from handeye_jax import load_dataset
from handeye_jax.cli import main
from handeye_jax.data import Camera, read_intrinsics, realsense_difference_px
from tests.common import PAPER

FX, FY, CX, CY = 615.25, 616.5, 320.75, 239.5
D = (-0.0555, 0.0665, -0.0004, 0.0007, -0.0213)
WANT = Camera(FX, FY, CX, CY, D)
K = [FX, 0.0, CX, 0.0, FY, CY, 0.0, 0.0, 1.0]


def _write_all(folder):
    """The same camera in each format; the YAML ones dumped by PyYAML, OpenCV's by OpenCV."""
    files = {}
    files["camera_info.yaml"] = yaml.safe_dump({
        "image_width": 640, "image_height": 480, "camera_name": "color",
        "camera_matrix": {"rows": 3, "cols": 3, "data": K},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": list(D)},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": [1, 0, 0, 0, 1, 0, 0, 0, 1]},
        "projection_matrix": {"rows": 3, "cols": 4, "data": [FX, 0, CX, 0, 0, FY, CY, 0, 0, 0,
                                                             1, 0]},
    })  # fmt: skip
    files["echo.yaml"] = yaml.safe_dump({
        "header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "camera_color_optical_frame"},
        "height": 480, "width": 640, "distortion_model": "plumb_bob", "d": list(D), "k": K,
        "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1], "p": [FX, 0, CX, 0, 0, FY, CY, 0, 0, 0, 1, 0],
        "binning_x": 0, "binning_y": 0,
    }) + "---\n"  # fmt: skip
    files["rs.json"] = json.dumps({"width": 640, "height": 480, "ppx": CX, "ppy": CY, "fx": FX,
                                   "fy": FY, "model": "Brown Conrady", "coeffs": list(D)})
    files["rs_inverse.json"] = json.dumps({"color": {
        "width": 640, "height": 480, "ppx": CX, "ppy": CY, "fx": FX, "fy": FY,
        "model": "Inverse Brown Conrady", "coeffs": list(D)}})  # fmt: skip
    for name, text in files.items():
        (folder / name).write_text(text)
    Km = np.array(K).reshape(3, 3)
    for name, key_k, key_d, d in (("calib.yml", "camera_matrix", "distortion_coefficients",
                                   np.array([D])),
                                  ("calib.xml", "cameraMatrix", "distCoeffs",
                                   np.array([*D, 0.0, 0.0, 0.0]))):  # fmt: skip
        fs = cv2.FileStorage(str(folder / name), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", 640)
        fs.write("image_height", 480)
        fs.write(key_k, Km)
        fs.write(key_d, d)
        fs.release()
        files[name] = None
    return list(files)


def test_every_format_gives_the_same_camera(tmp_path):
    for name in _write_all(tmp_path):
        assert read_intrinsics(tmp_path / name) == WANT, name


def test_realsense_variants_within_a_hundredth_of_a_pixel_are_read_as_plumb_bob():
    # librealsense applies the tangential terms to the radially distorted point; for a
    # RealSense-like lens that moves no pixel of a 640 x 480 picture by 0.01 px.
    small = realsense_difference_px((FX, FY, CX, CY), D, (640, 480))
    assert 0 < small < 0.01
    assert realsense_difference_px((FX, FY, CX, CY), (-0.4, 0.2, 0.01, 0.01, 0), (640, 480)) > 0.01


def test_intrinsics_command_sets_the_camera_in_place(tmp_path, capsys):
    _write_all(tmp_path)
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    assert main(["intrinsics", str(tmp_path / "echo.yaml"), "--dataset", str(ds)]) == 0
    out = capsys.readouterr().out
    assert "fx 615.25, fy 616.5, cx 320.75, cy 239.5 px" in out and "plumb_bob" in out
    assert load_dataset(ds).camera == WANT
    assert "[camera]  # pinhole intrinsics, px" in ds.read_text()  # the comments stay
    assert len(list(tmp_path.glob("rig.toml.*.bak"))) == 1


BAD = {
    "unknown_model.yaml": ("k: [600, 0, 320, 0, 600, 240, 0, 0, 1]\nd: [0.1, 0, 0, 0, 0]\n"
                           "distortion_model: equidistant\n",
                           "distortion_model: is 'equidistant': only plumb_bob"),
    "rational.yaml": ("k: [600, 0, 320, 0, 600, 240, 0, 0, 1]\nd: [0.1, 0, 0, 0, 0, 0.2, 0, 0]\n"
                      "distortion_model: rational_polynomial\n", "non-zero coefficients beyond k3"),
    "skew.yaml": ("k: [600, 3, 320, 0, 600, 240, 0, 0, 1]\n", "camera_matrix: is not a pinhole"),
    "short.yaml": ("k: [600, 0, 320, 0, 600, 240]\n", "k: must be 9 numbers"),
    "nan.json": ('{"fx": NaN, "fy": 600, "ppx": 320, "ppy": 240}', "fx: must be a finite number"),
    "strong.json": ('{"fx": 600, "fy": 600, "ppx": 320, "ppy": 240, "width": 640, "height": 480,'
                    ' "model": "Inverse Brown Conrady", "coeffs": [-0.4, 0.2, 0.01, 0.01, 0]}',
                    "model: 'Inverse Brown Conrady': its tangential terms differ"),
    "nothing.yaml": ("image_width: 640\n", "camera_matrix: missing"),
    "binary.yaml": ("\x00\x01{{{", "not"),
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_intrinsics_are_one_line_naming_file_and_field(tmp_path, capsys, name):
    text, why = BAD[name]
    path = tmp_path / name
    path.write_text(text)
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    before = ds.read_bytes()
    assert main(["intrinsics", str(path), "--dataset", str(ds)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and why in err and name in err, err
    assert ds.read_bytes() == before


def test_detect_reads_depth_in_tenth_millimetre_units(tmp_path, capsys):
    twin = tmp_path / "twin"
    assert main(["simulate", str(twin), "--seed", "1", "--heldout", "2"]) == 0
    depth = cv2.imread(str(twin / "depth.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(twin / "depth01.png"), (depth.astype(np.uint32) * 10).astype(np.uint16))
    capsys.readouterr()
    outs = {}
    for name, scale in (("depth.png", "1"), ("depth01.png", "0.1")):
        outs[scale] = tmp_path / f"d{scale}.toml"
        assert main(["detect", str(twin / "capture.png"), str(twin / name), "--dataset",
                     str(twin / "dataset.toml"), "--depth-scale-mm", scale, "--out",
                     str(outs[scale])]) == 0  # fmt: skip
        out = capsys.readouterr().out
        assert f"{scale} mm per unit, aligned to the picture pixel for pixel" in out
    a, b = (load_dataset(p).depth_mm for p in outs.values())
    assert np.array_equal(a, b) and (150 < a).all() and (a < 200).all()
    # The wrong scale: ten times too deep, and said so.
    assert main(["detect", str(twin / "capture.png"), str(twin / "depth01.png"), "--dataset",
                 str(twin / "dataset.toml"), "--out", str(tmp_path / "wrong.toml")]) == 0
    assert "check the depth scale" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["detect", str(twin / "capture.png"), str(twin / "depth.png"), "--dataset",
              str(twin / "dataset.toml"), "--depth-scale-mm", "0"])
    assert e.value.code == 2
    assert "--depth-scale-mm: must be > 0" in capsys.readouterr().err
