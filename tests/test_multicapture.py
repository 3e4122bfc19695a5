"""Several captures: each view through its own capture pose, the hand's heights, and commands
(x, y, z) from capture poses the calibration never used, on noise-free data with known truth."""

from dataclasses import replace

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import handeye_jax
from handeye_jax import (
    HTMModel,
    InputError,
    Predictor,
    Rig,
    Scene,
    Settings,
    Stage1Objective,
    calibrate,
    geometry,
    get_model,
    load_result,
    save_result,
    snake_grid_px,
    synthesize_dataset,
)
from handeye_jax.data import read_capture_columns, read_points_csv
from handeye_jax.twin import seen_from, true_command
from tests.common import EXACT_RESTARTS, FAST_SETTINGS

TRUTH = {
    "htm": dict(xc=-3.0, yc=35.0, alpha_c=-1.5, beta_c=2.0, gamma_c=4.0, xt=150.0, yt=40.0,
                alpha_t=2.0, beta_t=-8.0, gamma_t=-3.0, xp=4.0, yp=-25.0),
    "dh": dict(theta_c1=5.0, a_c1=60.0, alpha_c=8.0, beta_c=-2.0, gamma_c=-10.0, theta_t1=30.0,
               a_t1=140.0, alpha_t=20.0, beta_t=-4.0, gamma_t=-12.0, xp=-3.0, yp=-22.0),
}  # fmt: skip
CAMERA_Z_MM, PEN_Z_MM, TABLET_Z_MM = 3.0, 7.0, 120.0


def _truth(model):
    with handeye_jax.float64():
        return get_model(model).from_dict(TRUTH[model])


def _poses(zero, sign):
    """Three captures 100 mm apart in height, at three hand angles (θ at φ = 0, +15, −20)."""
    a0 = -zero * sign
    return [([320.0, -70.0, 290.0], a0), ([330.0, -80.0, 350.0], a0 + 15.0),
            ([310.0, -50.0, 390.0], a0 - 20.0)]  # fmt: skip


def _dataset(model, zero, sign, pen_z=PEN_Z_MM):
    rig = Rig(617.7, 617.7, 316.5, 242.3, [320.0, -70.0, 290.0], zero, sign)
    scene = Scene(camera_z_mm=CAMERA_Z_MM, tablet_height_mm=TABLET_Z_MM, pen_z_mm=pen_z)
    ds = synthesize_dataset(_truth(model), rig, snake_grid_px(), 22.5 * np.arange(9),
                            captures=_poses(zero, sign), scene=scene)  # fmt: skip
    return rig, ds


def _targets(model, rig, seed=0, k=10):
    """Points above the tablet (0 to 60 mm), seen from a capture pose no fit used, with the
    hand angles to touch them and the true commands (x, y, z)."""
    truth = _truth(model)
    rng = np.random.default_rng(seed)
    with handeye_jax.float64():
        mm = 25.4 / 267.0 * 2.0
        x_bt = np.asarray(truth.tablet_to_base(jnp.asarray(snake_grid_px() * mm)))
    lo, hi = x_bt.min(axis=0), x_bt.max(axis=0)
    p = np.c_[rng.uniform(lo[0], hi[0], k), rng.uniform(lo[1], hi[1], k),
              TABLET_Z_MM + rng.uniform(0.0, 60.0, k)]  # fmt: skip
    position = np.array([300.0, -40.0, 340.0])
    angle = float(-rig.angle_zero_deg * rig.angle_sign) + 35.0
    uv, depth = seen_from(truth, rig, p, position, angle, camera_z_mm=CAMERA_Z_MM)
    theta = rng.uniform(0.0, 180.0, k)
    return uv, depth, theta, position, angle, true_command(truth, rig, p, theta,
                                                           pen_z_mm=PEN_Z_MM)  # fmt: skip


@given(
    st.lists(st.floats(-300, 300), min_size=3, max_size=3),
    st.floats(-720, 720),
    st.lists(st.floats(-500, 500), min_size=3, max_size=3),
)
@settings(max_examples=30, deadline=None)
def test_hand_to_base_is_eq1_turned_by_phi(p, phi, t):
    """``Ry(-180)·Rz(φ)·p + t``, the hand pointing down turned by φ."""
    with handeye_jax.float64():
        R = geometry.rot_y(-180.0) @ geometry.rot_z(phi)
        want = R @ jnp.asarray(p) + jnp.asarray(t)
        got = geometry.hand_to_base(jnp.asarray([p]), jnp.asarray([phi]), jnp.asarray([t]))[0]
    np.testing.assert_allclose(got, want, atol=1e-9)


@pytest.mark.parametrize("zero,sign", [(90.0, -1), (0.0, 1), (30.0, -1)])
def test_capture_angle_turns_the_camera_with_the_hand(zero, sign):
    """A rig given its capture's hand angle: at φ = 0 the paper's eq. (1); at another angle
    ``Ry(-180)·Rz(φc)`` with ``φc = zero + sign·θc``."""
    with handeye_jax.float64():
        paper = Rig(600, 600, 320, 240, [1.0, 2.0, 3.0], zero, sign)
        at_zero = Rig(600, 600, 320, 240, [1.0, 2.0, 3.0], zero, sign, -zero * sign)
        turned = Rig(600, 600, 320, 240, [1.0, 2.0, 3.0], zero, sign, 40.0)
        np.testing.assert_allclose(at_zero.T_base_hand_capture()[0],
                                   paper.T_base_hand_capture()[0], atol=1e-15)  # fmt: skip
        want = geometry.rot_y(-180.0) @ geometry.rot_z(zero + sign * 40.0)
        np.testing.assert_allclose(turned.T_base_hand_capture()[0], want, atol=1e-15)


def test_simple_dataset_keeps_the_paper_rows():
    rig = Rig(617.7, 617.7, 316.5, 242.3, [320.0, -70.0, 290.0], 90.0, -1)
    ds = synthesize_dataset(_truth("htm"), rig, snake_grid_px(), 22.5 * np.arange(9))
    obs = ds.observations()
    assert not obs.per_capture and obs.hand_z_mm is None and obs.n_landmarks == 9
    assert ds.n_rows == 9 and obs.rig.capture_hand_angle_deg is None


def test_rows_pair_each_view_with_each_touch_and_skip_missing_landmarks():
    """Capture 2 misses landmarks 0 and 5: 9 + 9 + 7 rows, each with its capture's pose; the
    truth explains every row exactly (x-y and z blocks)."""
    rig, full = _dataset("htm", 90.0, -1)
    caps = list(full.captures)
    c = caps[2]
    keep = np.array([m not in (0, 5) for m in c.landmarks])
    caps[2] = type(c)(c.hand_position_mm, c.hand_angle_deg, c.landmarks[keep], c.image_px[keep],
                      c.depth_mm[keep])  # fmt: skip
    ds = full.replace(captures=caps)
    obs = ds.observations()
    assert obs.per_capture and ds.n_rows == obs.n_landmarks == 25
    np.testing.assert_array_equal(np.asarray(obs.capture_index), [0] * 9 + [1] * 9 + [2] * 7)
    np.testing.assert_array_equal(np.asarray(obs.capture_position_mm)[-1], c.hand_position_mm)
    with handeye_jax.float64():
        terms = Stage1Objective(HTMModel, obs).terms(_truth("htm").to_vector())
    assert set(terms) == {"f1", "f2", "f1z", "f2z"}
    assert max(float(v) for v in terms.values()) < 1e-9


@pytest.fixture(scope="module", params=[("htm", 90.0, -1), ("htm", 0.0, 1), ("dh", 90.0, -1),
                                        ("dh", 0.0, 1)])  # fmt: skip
def fitted(request):
    model, zero, sign = request.param
    rig, ds = _dataset(model, zero, sign)
    return model, rig, ds, calibrate(ds, replace(FAST_SETTINGS, model=model, seed=0,
                                                 restarts=EXACT_RESTARTS))


@pytest.mark.slow
def test_noise_free_captures_are_recovered(fitted):
    """F < 1e-6 mm; z_p − z_c recovered; commands (x, y, z) to 1e-6 mm for points off the
    tablet plane seen from a capture pose no fit used; the NumPy predictor agrees to 1e-9."""
    model, rig, _, r = fitted
    assert r.stage1.F < 1e-6 and r.stage2.F < 1e-6, (r.stage1.F, r.stage2.F)
    assert abs(r.heights.pen_minus_camera_mm - (PEN_Z_MM - CAMERA_Z_MM)) < 1e-6
    assert abs(r.heights.tablet_plus_camera_mm - (TABLET_Z_MM + CAMERA_Z_MM)) < 1e-6
    uv, depth, theta, position, angle, want = _targets(model, rig)
    for stage in (1, 2):
        got = r.predict(uv, depth, theta, stage=stage, capture_position_mm=position,
                        capture_hand_angle_deg=angle, axes="xyz")  # fmt: skip
        assert np.abs(got - want).max() < 1e-6, stage
    pred = Predictor.from_frames(r.frames())
    assert pred.axes == "xyz"
    got = pred.hand_command(uv, depth, theta, capture_position_mm=position,
                            capture_hand_angle_deg=angle, axes="xyz")  # fmt: skip
    jax_cmd = r.predict(uv, depth, theta, capture_position_mm=position,
                        capture_hand_angle_deg=angle, axes="xyz")  # fmt: skip
    assert np.abs(got - jax_cmd).max() < 1e-9


def test_the_result_file_keeps_captures_and_heights(fitted, tmp_path):
    model, rig, ds, r = fitted
    path = tmp_path / "r.json"
    save_result(r, path)
    back = load_result(path)
    assert back.data == ds and back.heights == r.heights
    # The heights give the views a z: the depth's noise scale is the data's own, and kept.
    assert r.stage1.noise.noise.depth_scale is not None and back.stage1.noise == r.stage1.noise
    uv, depth, theta, position, angle, want = _targets(model, rig, seed=1, k=4)
    got = back.predict(uv, depth, theta, capture_position_mm=position,
                       capture_hand_angle_deg=angle, axes="xyz")  # fmt: skip
    assert np.abs(got - want).max() < 1e-6
    got = Predictor.from_result(path).hand_command(
        uv, depth, theta, capture_position_mm=position, capture_hand_angle_deg=angle, axes="xyz"
    )
    assert np.abs(got - want).max() < 1e-6


def test_without_hand_heights_there_is_no_z():
    _, ds = _dataset("htm", 90.0, -1, pen_z=None)
    assert not ds.has_hand_z
    obs = ds.observations()
    assert obs.per_capture and obs.hand_z_mm is None
    with handeye_jax.float64():
        terms = Stage1Objective(HTMModel, obs).terms(_truth("htm").to_vector())
    assert set(terms) == {"f1", "f2"}


def test_points_csv_capture_columns(tmp_path):
    good = tmp_path / "p.csv"
    good.write_text("u,v,depth,hand_angle,capture_x,capture_y,capture_z,capture_angle\n"
                    "1,2,300,10,100,-50,400,30\n3,4,310,20,110,-40,420,-15\n")  # fmt: skip
    header, rows, _ = read_points_csv(good)
    position, angle = read_capture_columns(good, header, rows)
    np.testing.assert_array_equal(position, [[100, -50, 400], [110, -40, 420]])
    np.testing.assert_array_equal(angle, [30, -15])
    plain = tmp_path / "q.csv"
    plain.write_text("u,v,depth,hand_angle\n1,2,300,10\n")
    assert read_capture_columns(plain, *read_points_csv(plain)[:2]) == (None, None)
    bad = tmp_path / "b.csv"
    bad.write_text("u,v,depth,hand_angle,capture_x,capture_y\n1,2,300,10,1,2\n")
    with pytest.raises(InputError, match="capture_z"):
        read_capture_columns(bad, *read_points_csv(bad)[:2])
    nan = tmp_path / "n.csv"
    nan.write_text("u,v,depth,hand_angle,capture_angle\n1,2,300,10,nan\n")
    with pytest.raises(InputError, match="line 2.capture_angle"):
        read_capture_columns(nan, *read_points_csv(nan)[:2])


def test_exports_carry_the_height(fitted):
    """The JSON frames document and the standalone Python module give the same (x, y, z)."""
    import json

    from handeye_jax import Frames, export_text

    model, rig, _, r = fitted
    frames = r.frames()
    uv, depth, theta, position, angle, want = _targets(model, rig, seed=2, k=5)
    again = Frames.from_dict(json.loads(export_text(frames, "json")))
    assert again.pen_minus_camera_z_mm == frames.pen_minus_camera_z_mm
    namespace: dict = {}
    exec(compile(export_text(frames, "python"), "handeye_calibration.py", "exec"), namespace)
    got = namespace["hand_command"](uv, depth, theta, capture_position_mm=position,
                                    capture_hand_angle_deg=angle, axes="xyz")  # fmt: skip
    assert np.abs(got - want).max() < 1e-6


# -- the twin ----------------------------------------------------------------------------------


@pytest.fixture(scope="module", params=[1, 4])  # conventions (90°, −1) and (0°, +1)
def exact_twin(request, tmp_path_factory):
    """A noise-free three-capture twin written to a folder, and its calibration."""
    from handeye_jax import PRESETS, draw_truth, simulate, write_twin

    truth = replace(draw_truth(request.param, dot_px=2.0), pen_z_mm=95.0)
    twin = simulate(truth, PRESETS["none"], request.param, exact=True, n_heldout=5, captures=3)
    folder = tmp_path_factory.mktemp(f"twin{request.param}")
    write_twin(twin, folder)
    return twin, folder, calibrate(twin.dataset,
                                     replace(FAST_SETTINGS, seed=0, restarts=EXACT_RESTARTS))


def test_twin_draws_captures_at_several_heights_and_hand_angles(exact_twin):
    twin, folder, _ = exact_twin
    caps = twin.dataset.captures
    z = [c.hand_position_mm[2] for c in caps]
    assert len(caps) == 3 and max(z) - min(z) >= 80.0
    assert len({round(c.hand_angle_deg, 6) for c in caps}) == 3
    assert twin.dataset.has_hand_z and twin.dataset.version == 2
    for name in ("capture_1.png", "depth_2.png", "heldout.csv", "dataset.toml"):
        assert (folder / name).is_file()
    rises = twin.heldout_capture_position_mm[:, 2] - z[0]
    assert set(np.round(rises, 9)) == {0.0, 60.0} and set(twin.heldout_above_mm) == {0.0, 50.0}


def test_heldout_levels_draw_n_each_per_rise_and_height_and_refuse_a_bad_field(exact_twin):
    from handeye_jax import PRESETS
    from handeye_jax.twin import HeldoutLevels, heldout_targets

    twin = exact_twin[0]
    assert HeldoutLevels(5) == HeldoutLevels(5, (0.0, 60.0), (0.0, 50.0))  # the twin's own
    levels = HeldoutLevels(2, rises_mm=[0, 30], above_mm=(0.0, 10.0, 20.0))
    assert levels.rises_mm == (0.0, 30.0)  # a list becomes a tuple of floats
    held = heldout_targets(twin.truth, PRESETS["none"], np.random.default_rng(3), levels,
                           exact=True)  # fmt: skip
    assert held["heldout_tablet_px"].shape == (2 * 2 * 3, 2)
    assert list(held["heldout_above_mm"]) == [0.0] * 2 + [10.0] * 2 + [20.0] * 2 + \
        [0.0] * 2 + [10.0] * 2 + [20.0] * 2  # fmt: skip
    for bad, field in (({"n_each": 0}, "n_each"), ({"n_each": 10_001}, "n_each"),
                       ({"n_each": 2.0}, "n_each"), ({"rises_mm": ()}, "rises_mm"),
                       ({"above_mm": (0.0, float("nan"))}, "above_mm"),
                       ({"above_mm": (-5.0,)}, "above_mm")):  # fmt: skip
        with pytest.raises(ValueError, match=rf"^{field}: must"):
            HeldoutLevels(**{"n_each": 3, **bad})


def test_captures_given_as_poses_make_the_twin_their_count_draws():
    """``captures=[poses]`` takes those poses, and every other draw is the count's: the twin
    of the poses that ``captures=3`` drew is that twin, picture for picture."""
    from handeye_jax import PRESETS, draw_truth, simulate

    truth = draw_truth(1, dot_px=2.0)
    twin = simulate(truth, PRESETS["paper"], 7, n_heldout=3, captures=3)
    poses = [(c.hand_position_mm, c.hand_angle_deg) for c in twin.dataset.captures]
    again = simulate(truth, PRESETS["paper"], 7, n_heldout=3, captures=poses)
    for a, b in zip(again.dataset.captures, twin.dataset.captures, strict=True):
        np.testing.assert_array_equal(a.hand_position_mm, b.hand_position_mm)
        np.testing.assert_array_equal(a.image_px, b.image_px)
        np.testing.assert_array_equal(a.depth_mm, b.depth_mm)
    np.testing.assert_array_equal(again.capture, twin.capture)
    np.testing.assert_array_equal(again.dataset.hand_xy_mm, twin.dataset.hand_xy_mm)
    np.testing.assert_array_equal(again.heldout_image_px, twin.heldout_image_px)
    moved = [(p + [0.0, 0.0, 5.0], a + 1.0) for p, a in poses]
    other = simulate(truth, PRESETS["none"], 7, exact=True, n_heldout=3, captures=moved)
    for c, (p, a) in zip(other.dataset.captures, moved, strict=True):
        np.testing.assert_array_equal(c.hand_position_mm, p)
        assert c.hand_angle_deg == a
    with pytest.raises(ValueError, match="captures must be 1 to"):
        simulate(truth, PRESETS["none"], 1, captures=poses * 3)


def test_exact_twin_is_recovered_from_any_capture_pose(exact_twin):
    """The renderer (a rotation matrix per capture) and the fit (eq. 1 turned by φc) agree
    under the twin's hand-angle convention: F < 1e-6 mm, and x-y and z commands to 1e-6 mm
    for targets on and 50 mm above the display, seen from the first capture and from a new
    pose 60 mm higher at another hand angle."""
    from handeye_jax import evaluate_twin, format_evaluation

    twin, folder, r = exact_twin
    assert r.stage1.F < 1e-6 and r.stage2.F < 1e-6, (r.stage1.F, r.stage2.F)
    dz = twin.truth.pen_z_mm - twin.truth.camera_z_mm
    assert abs(r.heights.pen_minus_camera_mm - dz) < 1e-6
    path = folder / "result.json"
    save_result(r, path)
    rows = evaluate_twin(path, folder)
    assert [e.label for e in rows] == ["stage 1", "stage 2", "oracle", "oracle + stage 2"]
    for e in rows:
        assert e.xy_mm.max() < 1e-6 and e.z_mm.max() < 1e-6, e.label
    table = format_evaluation(rows)
    assert "| 60 | 50 | 5 |" in table and "capture above the first" in table


def test_predict_command_reads_capture_columns_and_writes_hand_z(fitted, tmp_path):
    """`predict` takes each point's capture pose from the CSV and appends hand_z: the same
    numbers as the Python API, and the truth to 1e-6 mm (the CSV keeps 6 decimals)."""
    from handeye_jax.cli import main

    model, rig, _, r = fitted
    result = tmp_path / "r.json"
    save_result(r, result)
    uv, depth, theta, position, angle, want = _targets(model, rig, seed=3, k=3)
    points = tmp_path / "p.csv"
    rows = ["u,v,depth,hand_angle,capture_x,capture_y,capture_z,capture_angle"]
    rows += [",".join(repr(float(x)) for x in (*uv[i], depth[i], theta[i], *position, angle))
             for i in range(3)]  # fmt: skip
    points.write_text("\n".join(rows) + "\n")
    out = tmp_path / "out.csv"
    assert main(["predict", str(result), str(points), "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[0].endswith(",hand_x,hand_y,hand_z")
    got = np.array([[float(x) for x in line.split(",")[-3:]] for line in lines[1:]])
    assert np.abs(got - want).max() < 2e-6


@pytest.mark.slow
def test_summary_says_where_the_calibration_holds():
    """One capture: the camera shift/tilt trade-off is reported and the covariance expects a
    much larger error from a capture 50 mm away; three captures: the trade-off is gone and
    the error stays about the same. Hand positions rounded to 0.1 mm give the fit a spread."""
    from handeye_jax import diagnose, format_summary

    rig, ds3 = _dataset("htm", 90.0, -1)
    ds1 = synthesize_dataset(_truth("htm"), rig, snake_grid_px(), 22.5 * np.arange(9))
    # The paper's loss: the scope's errors from its Gauss-Newton covariance (the ML fit's
    # scope is not validated yet; benchmarks/RESULTS.md, issue 26).
    s = Settings(seed=0, population=200, generations=300, loss="l1")
    scopes = {}
    for k, ds in ((1, ds1), (3, ds3)):
        ds = ds.replace(hand_xy_mm=np.round(ds.hand_xy_mm, 1))
        r = diagnose(calibrate(ds, s))
        scopes[k] = (r.diagnostics.scope, format_summary(r, verbose=True))
    one, text1 = scopes[1]
    three, text3 = scopes[3]
    assert one.captures == 1 and one.camera_tradeoffs
    e = one.expected_error_mm
    assert min(e["+50"], e["-50"]) > 5 * e["+0"]
    assert "scope: one capture: the calibration holds only for pictures taken from this" in text1
    assert "heights: the touches recorded no hand height" in text1
    assert three.captures == 3 and not three.camera_tradeoffs
    e = three.expected_error_mm
    assert max(e["+50"], e["-50"]) < 3 * e["+0"]
    assert "trade-offs of a single picture (xc/βc, yc/αc) are gone" in text3
    assert "z_pen − z_camera = 4.000" in text3
