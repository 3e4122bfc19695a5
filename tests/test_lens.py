"""Lens distortion (issue 25): plumb_bob undistortion agrees with OpenCV's, a dataset carries
it in [camera], the fit, the Predictor and the exports undistort with it, and a noise-free
twin seen through a RealSense-like lens calibrates exactly with the model and not without."""

from __future__ import annotations

import dataclasses
import importlib.util

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from handeye_jax import (
    PRESETS,
    Predictor,
    calibrate,
    draw_truth,
    load_dataset,
    save_dataset,
    simulate,
)
from handeye_jax.cli import main
from handeye_jax.data import Camera, distort_px, undistort_px
from handeye_jax.robot import export_text
from handeye_jax.twin import REALSENSE_LIKE
from tests.common import EXACT_RESTARTS, FAST_SETTINGS, PAPER

EXACT = dataclasses.replace(FAST_SETTINGS, restarts=EXACT_RESTARTS)  # noise-free twins' fits
CAMERA = (615.0, 616.0, 321.5, 238.25)
K = np.array([[CAMERA[0], 0.0, CAMERA[2]], [0.0, CAMERA[1], CAMERA[3]], [0.0, 0.0, 1.0]])
CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-16)


def cv_undistort(uv: np.ndarray, coeffs, camera=CAMERA) -> np.ndarray:
    """OpenCV's undistortion to pinhole pixels (P = K), iterated to convergence (the API took
    its criteria in undistortPointsIter before OpenCV 5)."""
    fx, fy, cx, cy = camera
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    pts = np.asarray(uv, float).reshape(-1, 1, 2)
    D = np.asarray(coeffs, float)
    if hasattr(cv2, "undistortPointsIter"):
        out = cv2.undistortPointsIter(pts, K, D, None, K, CRITERIA)
    else:
        out = cv2.undistortPoints(pts, K, D, P=K, criteria=CRITERIA)
    return out.reshape(-1, 2)


coefficients = st.tuples(
    st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.005, 0.005),
    st.floats(-0.005, 0.005), st.floats(-0.1, 0.1),
)  # fmt: skip


@settings(max_examples=40, deadline=None)
@given(coefficients, st.integers(0, 2**32 - 1))
def test_undistortion_is_opencvs_and_inverts_projectpoints(coeffs, seed):
    rng = np.random.default_rng(seed)
    ideal = rng.uniform([40, 30], [600, 450], (50, 2))  # pinhole pixels of a 640 x 480 view
    rays = np.c_[(ideal - CAMERA[2:]) / CAMERA[:2], np.ones(50)]
    seen = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, np.array(coeffs))[0].reshape(-1, 2)
    assert np.abs(distort_px(ideal, CAMERA, coeffs) - seen).max() < 1e-9
    ours = undistort_px(seen, CAMERA, coeffs)
    assert np.abs(ours - ideal).max() < 1e-8
    assert np.abs(ours - cv_undistort(seen, coeffs)).max() < 1e-8


def test_no_distortion_is_the_identity_and_a_hopeless_point_is_nan():
    uv = np.array([[10.0, 20.0], [600.0, 400.0]])
    assert undistort_px(uv, CAMERA, None) is not None
    assert np.array_equal(undistort_px(uv, CAMERA, None), uv)
    # Barrel so strong that the lens folds the picture's corner back: no inverse there.
    bad = undistort_px(np.array([[0.0, 0.0], [321.5, 238.25]]), CAMERA, (-2.0, 0, 0, 0, 0))
    assert np.isnan(bad[0]).all() and np.allclose(bad[1], [321.5, 238.25])


def test_dataset_carries_distortion_and_observations_undistort(tmp_path):
    ds = load_dataset(PAPER)
    lens = ds.replace(camera=Camera(*ds.camera.px, REALSENSE_LIKE))
    path = tmp_path / "lens.toml"
    save_dataset(lens, path)
    assert "distortion = [-0.0555, 0.0665, -0.0004, 0.0007, -0.0213]" in path.read_text()
    back = load_dataset(path)
    assert back == lens and back.camera.distortion == REALSENSE_LIKE
    got = np.asarray(back.observations().image_px)
    assert np.abs(got - cv_undistort(ds.image_px, REALSENSE_LIKE, ds.camera.px)).max() < 1e-8
    assert np.abs(got - ds.image_px).max() > 0.5  # it did move them
    assert np.array_equal(np.asarray(ds.observations().image_px), ds.image_px)  # none: as given


@pytest.mark.parametrize("bad, why", [
    ("distortion = [0.1, 0.0, 0.0, 0.0]", "camera.distortion: must be an array of 5 numbers"),
    ('distortion = [0.1, 0.0, 0.0, 0.0, "a"]', "camera.distortion[4]: must be a number"),
    ("distortion = [-5.0, 0.0, 0.0, 0.0, 0.0]", "cannot be undistorted"),
])  # fmt: skip
def test_bad_distortion_is_one_line_naming_the_field(tmp_path, capsys, bad, why):
    text = PAPER.read_text().replace("cy = 242.3\n", f"cy = 242.3\n{bad}\n")
    path = tmp_path / "bad.toml"
    path.write_text(text)
    assert main(["calibrate", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and why in err and str(path) in err


@pytest.fixture(scope="module")
def lens_twin():
    """A noise-free three-capture twin seen through a RealSense-like lens (exact points)."""
    truth = dataclasses.replace(draw_truth(4, dot_px=2.0), distortion=REALSENSE_LIKE)
    return truth, simulate(truth, PRESETS["none"], 4, exact=True, n_heldout=5, captures=3)


@pytest.fixture(scope="module")
def lens_fit(lens_twin):
    """The lens twin calibrated with the distortion in its [camera]."""
    return calibrate(lens_twin[1].dataset, EXACT)


def test_the_twin_renders_through_its_lens(lens_twin):
    truth, twin = lens_twin
    pin = dataclasses.replace(truth, distortion=None)
    uv, _ = truth.project(truth.landmarks_tablet_px)
    ideal, _ = pin.project(truth.landmarks_tablet_px)
    assert np.abs(truth.undistort(uv) - ideal).max() < 1e-9
    assert np.abs(uv - ideal).max() > 0.5
    assert twin.dataset.camera.distortion == REALSENSE_LIKE


def test_noise_free_lens_twin_calibrates_exactly_with_the_model_only(lens_twin, lens_fit,
                                                                    tmp_path):  # fmt: skip
    truth, twin = lens_twin
    ds = twin.dataset
    with_model = lens_fit
    without = calibrate(ds.replace(camera=Camera(*ds.camera.px)), EXACT)
    assert with_model.stage1.F < 1e-6
    assert without.stage1.F > 100 * max(with_model.stage1.F, 1e-4)
    # The Predictor, the JAX path and the exported module undistort alike.
    from handeye_jax import save_result

    path = tmp_path / "r.json"
    save_result(with_model, path)
    pred = Predictor.from_result(path)
    assert pred.frames.distortion == REALSENSE_LIKE
    args = (twin.heldout_image_px, twin.heldout_depth_mm, twin.heldout_hand_angle_deg)
    pose = dict(capture_position_mm=twin.heldout_capture_position_mm,
                capture_hand_angle_deg=twin.heldout_capture_angle_deg)  # fmt: skip
    got = pred.hand_command(*args, **pose)
    assert np.abs(got - with_model.predict(*args, **pose)).max() < 1e-9
    want = truth.true_command(twin.heldout_true_mm, twin.heldout_hand_angle_deg)[:, :2]
    assert np.abs(got - want).max() < 1e-4
    module = tmp_path / "handeye_calibration.py"
    module.write_text(export_text(pred.frames, "python"))
    spec = importlib.util.spec_from_file_location("lens_module", module)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.DISTORTION == REALSENSE_LIKE
    assert np.abs(mod.hand_command(*args, capture_position_mm=pose["capture_position_mm"],
                                   capture_hand_angle_deg=pose["capture_hand_angle_deg"])
                  - got).max() < 1e-9  # fmt: skip
    fs = cv2.FileStorage(export_text(pred.frames, "opencv"),
                         cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)  # fmt: skip
    assert np.array_equal(fs.getNode("distortion_coefficients").mat().ravel(), REALSENSE_LIKE)


def test_predictor_refuses_a_point_the_lens_cannot_undistort(paper_result):
    strong = dataclasses.replace(paper_result.frames(), distortion=(-2.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"image_px\[0\] cannot be undistorted"):
        Predictor(strong).hand_command([[0.0, 0.0]], [170.0], [0.0])


def test_predict_reads_the_lens_and_an_edited_one_is_refused(lens_twin, lens_fit, tmp_path,
                                                              capsys):  # fmt: skip
    import json

    from handeye_jax import save_result

    truth, twin = lens_twin
    r = lens_fit
    path = tmp_path / "r.json"
    save_result(r, path)
    uv, depth = twin.heldout_image_px[:3], twin.heldout_depth_mm[:3]
    angle = twin.heldout_hand_angle_deg[:3]
    csv = tmp_path / "points.csv"
    lines = [f"{a:.9f},{b:.9f},{d:.9f},{t:.9f}\n"
             for (a, b), d, t in zip(uv, depth, angle, strict=True)]  # fmt: skip
    csv.write_text("u,v,depth,hand_angle\n" + "".join(lines))
    assert main(["predict", str(path), str(csv), "--stage", "1"]) == 0
    rows = [line.split(",") for line in capsys.readouterr().out.splitlines()[1:]]
    got = np.array([[float(x) for x in row[4:6]] for row in rows])
    assert np.abs(got - r.predict(uv, depth, angle, stage=1)).max() < 1e-5  # CSV: 6 decimals
    doc = json.loads(path.read_text())
    doc["frames"]["distortion"]["k1"] = 0.0
    path.write_text(json.dumps(doc))
    assert main(["predict", str(path), str(csv)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "frames.distortion" in err and "edited" in err
