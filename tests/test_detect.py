"""Landmark detection on the twin's pictures: accuracy, ordering, and one-line errors."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from handeye_jax import InputError, draw_truth, load_dataset, save_dataset, snake_grid_px
from handeye_jax.cli import main
from handeye_jax.twin import PRESETS, encode_png, simulate, write_twin
from handeye_jax.twin._render import true_depth_mm
from handeye_jax.vision import DetectSettings, depth_at, detect_landmarks, find_blobs, order_blobs

SEEDS = (11, 12, 13)


def _errors(preset: str, threshold: str = "otsu"):
    """Centroid errors (px) and depth errors (mm) of the detector against the truth."""
    uv_err, z_err = [], []
    for seed in SEEDS:
        twin = simulate(draw_truth(seed), PRESETS[preset], seed, exact=True, n_heldout=1)
        s = DetectSettings(threshold=threshold)
        blobs = find_blobs(twin.capture, s)
        assert len(blobs.image_px) == 9, blobs
        image_px = blobs.image_px[order_blobs(blobs.image_px, twin.truth.landmarks_tablet_px)]
        uv_err.append(image_px - twin.landmarks_image_px)
        z_err.append(depth_at(twin.depth, image_px) - twin.landmarks_depth_mm)
    return np.concatenate(uv_err), np.concatenate(z_err)


def _rms(e):
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def test_noise_free_centroids_within_0_1_px_and_depth_within_1_mm():
    uv, z = _errors("none")
    assert _rms(uv) <= 0.1 and np.abs(z).max() <= 1.0


def test_paper_preset_centroids_within_0_3_px_and_depth_within_1_mm():
    uv, z = _errors("paper")
    assert _rms(uv) <= 0.3 and np.abs(z).max() <= 1.0


def test_adaptive_threshold_finds_the_landmarks_too():
    uv, _ = _errors("none", threshold="adaptive")
    assert _rms(uv) <= 0.1


def test_rendered_depth_is_the_chains_depth():
    truth = draw_truth(5)
    uv, z = truth.project(truth.landmarks_tablet_px)
    depth = true_depth_mm(truth)
    u, v = np.round(uv).astype(int).T
    # The plane's slope over half a pixel is far below 0.1 mm at these tilts.
    assert np.abs(depth[v, u] - z).max() < 0.1


@settings(max_examples=40, deadline=None)
@given(
    turn_deg=st.floats(-30, 30),
    tilt=st.tuples(st.floats(-4e-4, 4e-4), st.floats(-4e-4, 4e-4)),
    scale=st.floats(0.4, 1.2),
    shift=st.tuples(st.floats(-50, 50), st.floats(-50, 50)),
    perm_seed=st.integers(0, 2**32 - 1),
)
def test_ordering_holds_under_rotation_and_perspective(turn_deg, tilt, scale, shift, perm_seed):
    layout = snake_grid_px()
    c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
    H = np.array([[scale * c, -scale * s, 320 + shift[0]], [scale * s, scale * c, 240 + shift[1]],
                  [tilt[0], tilt[1], 1.0]])  # fmt: skip
    centred = layout - layout.mean(axis=0)
    seen = cv2.perspectiveTransform(centred[None], H)[0]
    perm = np.random.default_rng(perm_seed).permutation(9)
    order = order_blobs(seen[perm], layout)
    np.testing.assert_array_equal(perm[order], np.arange(9))


@pytest.mark.parametrize("landmarks", [[0, 4, 5, 6, 7, 8], [2, 3, 4, 5, 8], [0, 1, 2, 5, 8]],
                         ids=["staircase", "T", "L"])  # fmt: skip
def test_a_layout_with_three_in_a_row_on_its_outline_is_ordered(landmarks):
    """Issue 23: its outermost four held three in a row (no quadrilateral): it was refused."""
    layout = snake_grid_px()[landmarks]
    centred = layout - layout.mean(axis=0)
    for turn_deg, tilt in [(0.0, (0.0, 0.0)), (5.0, (0.0, 2.9e-5)), (-20.0, (1e-4, -5e-5))]:
        c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
        H = np.array([[0.5 * c, -0.5 * s, 320.0], [0.5 * s, 0.5 * c, 240.0], [*tilt, 1.0]])
        seen = cv2.perspectiveTransform(centred[None], H)[0]
        perm = np.random.default_rng(len(landmarks)).permutation(len(landmarks))
        np.testing.assert_array_equal(perm[order_blobs(seen[perm], layout)],
                                      np.arange(len(landmarks)))  # fmt: skip


def test_ordering_on_a_rendered_grid_turned_30_deg_in_perspective():
    for gamma_t in (-30.0, 30.0):
        fixed = {"gamma_t": gamma_t, "alpha_t": 4.0, "depth_mm": 230.0}
        truth = draw_truth(2, fixed=fixed)
        twin = simulate(truth, PRESETS["none"], 0, exact=True, n_heldout=1)
        blobs = find_blobs(twin.capture)
        assert len(blobs.image_px) == 9
        got = blobs.image_px[order_blobs(blobs.image_px, truth.landmarks_tablet_px)]
        assert np.abs(got - twin.landmarks_image_px).max() < 0.2


@pytest.fixture(scope="module")
def twin_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("twin")
    write_twin(simulate(draw_truth(3), PRESETS["paper"], 3, n_heldout=3), folder)
    return folder


def test_detect_fills_image_px_and_depth_in_place_and_keeps_a_backup(twin_dir, tmp_path):
    ds_path = tmp_path / "data.toml"
    original = load_dataset(twin_dir / "dataset.toml")
    blank = original.replace(image_px=np.zeros((9, 2)) + 1.0, depth_mm=np.ones(9))
    save_dataset(blank, ds_path)
    before = ds_path.read_text()
    overlay = tmp_path / "overlay.png"
    args = [str(twin_dir / "capture.png"), str(twin_dir / "depth.png")]
    assert main(["detect", *args, "--dataset", str(ds_path), "--overlay", str(overlay)]) == 0
    (backup,) = tmp_path.glob("data.toml.*.bak")
    assert backup.read_text() == before
    filled = load_dataset(ds_path)
    assert filled == original  # the same detector made the twin's dataset
    assert filled.replace(image_px=blank.image_px, depth_mm=blank.depth_mm) == blank
    assert cv2.imread(str(overlay)).shape == (480, 640, 3)


def test_detect_out_leaves_the_dataset_alone(twin_dir, tmp_path):
    ds = twin_dir / "dataset.toml"
    text = ds.read_text()
    out = tmp_path / "new.toml"
    args = [str(twin_dir / "capture.png"), str(twin_dir / "depth.png")]
    assert main(["detect", *args, "--dataset", str(ds), "--out", str(out)]) == 0
    assert ds.read_text() == text and not list(twin_dir.glob("dataset.toml*.bak"))
    assert load_dataset(out) == load_dataset(ds)


def _fails(capsys, argv, *needles):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    for n in needles:
        assert n in err, err
    return err


def test_wrong_blob_count_reports_positions_and_writes_no_dataset(twin_dir, tmp_path, capsys):
    img = cv2.imread(str(twin_dir / "capture.png"))
    cv2.circle(img, (320, 20), 1, (0, 0, 0), -1)  # a tenth dark dot
    bad = tmp_path / "ten.png"
    bad.write_bytes(encode_png(img))
    out, overlay = tmp_path / "new.toml", tmp_path / "ov.png"
    ds = str(twin_dir / "dataset.toml")
    argv = ["detect", str(bad), str(twin_dir / "depth.png"), "--dataset", ds,
            "--out", str(out), "--overlay", str(overlay)]  # fmt: skip
    err = _fails(capsys, argv, "found 10 blobs, expected 9", str(bad), "(320.", "ov.png")
    assert not out.exists() and overlay.exists()
    assert "blobs" in err


def test_bad_images_are_one_line_errors(twin_dir, tmp_path, capsys):
    ds = str(twin_dir / "dataset.toml")
    cap, dep = str(twin_dir / "capture.png"), str(twin_dir / "depth.png")
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not a picture at all")
    small = tmp_path / "small.png"
    small.write_bytes(encode_png(np.full((240, 320), 170, np.uint16)))
    holes = tmp_path / "holes.png"
    holes.write_bytes(encode_png(np.zeros((480, 640), np.uint16)))
    _fails(capsys, ["detect", str(empty), dep, "--dataset", ds], "empty.png", "empty")
    _fails(capsys, ["detect", str(junk), dep, "--dataset", ds], "junk.png", "cannot read image")
    _fails(capsys, ["detect", cap, str(tmp_path / "none.png"), "--dataset", ds], "none.png")
    _fails(capsys, ["detect", cap, cap, "--dataset", ds], "16-bit")
    _fails(capsys, ["detect", cap, str(small), "--dataset", ds], "320x240", "640x480")
    _fails(capsys, ["detect", cap, str(holes), "--dataset", ds], "landmarks[0].depth", "no valid")
    assert sorted(p.name for p in twin_dir.iterdir() if p.suffix == ".bak") == []


def test_detect_landmarks_raises_input_error_naming_the_file(twin_dir):
    with pytest.raises(InputError, match=r"capture.png: blobs: found 9 blobs, expected 8"):
        detect_landmarks(twin_dir / "capture.png", twin_dir / "depth.png", snake_grid_px()[:8])


def test_collinear_blobs_or_layout_cannot_be_ordered():
    line = np.stack([np.linspace(100, 500, 9), np.full(9, 240.0)], axis=1)
    with pytest.raises(ValueError, match="blobs span no quadrilateral"):
        order_blobs(line, snake_grid_px())
    with pytest.raises(ValueError, match=r"drawn landmarks \(tablet_px\) span no quadrilateral"):
        order_blobs(snake_grid_px(), line)


def test_collinear_dots_are_a_one_line_input_error(twin_dir, tmp_path, capsys):
    img = np.full((480, 640), 235, np.uint8)
    for u in np.linspace(100, 540, 9):
        cv2.circle(img, (int(u), 240), 1, 120, -1)
    cap = tmp_path / "line.png"
    cap.write_bytes(encode_png(img))
    ds = str(twin_dir / "dataset.toml")
    _fails(capsys, ["detect", str(cap), str(twin_dir / "depth.png"), "--dataset", ds],
           "line.png: blobs: cannot order", "no quadrilateral")  # fmt: skip


def test_min_area_above_max_area_is_a_one_line_input_error(twin_dir, capsys):
    cap, dep, ds = (str(twin_dir / n) for n in ("capture.png", "depth.png", "dataset.toml"))
    _fails(capsys, ["detect", cap, dep, "--dataset", ds, "--min-area", "90"],
           "--min-area", "90 > 80")  # fmt: skip
