"""The bootstrap (issue 27 §2): a result refitted on resamples of its data in one batch, and how
far the commands of the stage to deploy move between the refits.

Known truth: on a noise-free twin every refit finds the truth, so the spread is 0; with noise
the spread grows in proportion to it (the same noise pattern, scaled), as the covariance's
prediction does. A seed gives the report bit for bit; the command line refuses a bad B in one
line; the workspace error map is drawn for a result that carries a bootstrap.

Each twin is small (9 landmarks) and the budget tiny, so the batch's programs compile fast."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from handeye_jax import (
    Bootstrap,
    Settings,
    bootstrap,
    calibrate,
    draw_truth,
    load_result,
    save_result,
    synthesize_dataset,
    write_report,
)
from handeye_jax.cli import main
from handeye_jax.data import Capture, snake_grid_px
from handeye_jax.diagnostics import resample, with_bootstrap

#: A budget small enough to compile and run fast (the restarts and refits still run).
SETTINGS = Settings(population=48, generations=60, restarts=4)
#: Resamples per bootstrap here.
B = 6
#: Image (px), depth (mm) and hand (mm) noise of the noisy twins, per axis, before scaling.
NOISE = (0.3, 0.5, 0.3)


def twin(seed: int = 3):
    """A noise-free twin: 3 × 3 landmarks, hand angles 22.5° apart."""
    truth = draw_truth(seed)
    px = snake_grid_px((400.0, 720.0, 1040.0), (150.0, 350.0, 550.0))
    return synthesize_dataset(truth.htm(), truth.rig(), px,
                              22.5 * np.arange(len(px))).replace(name=f"twin{seed}")


def noisy(ds, scale: float, seed: int = 7):
    """``ds`` with Gaussian noise (:data:`NOISE` times ``scale``) on its image points, depths
    and hand positions: the same draw for every scale."""
    rng = np.random.default_rng(seed)
    n = ds.n_landmarks
    s_px, s_depth, s_hand = (scale * s for s in NOISE)
    return ds.replace(image_px=ds.image_px + s_px * rng.standard_normal((n, 2)),
                      depth_mm=ds.depth_mm + s_depth * rng.standard_normal(n),
                      hand_xy_mm=ds.hand_xy_mm + s_hand * rng.standard_normal((n, 2)))  # fmt: skip


def fitted(ds):
    """The twin calibrated (its diagnostics skipped: the bootstrap then compares stage 1's
    commands, the stage deployed without evidence)."""
    return calibrate(ds, SETTINGS)


@pytest.fixture(scope="module")
def clean():
    return fitted(twin())


@pytest.fixture(scope="module")
def noisy_fits():
    return {k: fitted(noisy(twin(), k)) for k in (1.0, 4.0)}


@pytest.fixture(scope="module")
def noisy_boot(noisy_fits):
    return {k: bootstrap(r, B) for k, r in noisy_fits.items()}


def test_a_noise_free_twin_gives_no_spread(clean):
    boot = bootstrap(clean, B)
    assert boot.resamples == B and boot.fitted == B and boot.stage == clean.deploy_stage
    assert boot.spread_mean_mm < 1e-4 and boot.spread_p95_mm < 1e-3, boot
    assert np.max(boot.map.spread_mm) < 1e-3  # over the tablet, from the capture: exact
    # From another height it is not: one picture leaves the camera's shift against its tilt
    # (xc/βc, yc/αc) to the refits, which commands from the capture's own depth do not see.
    heights = dict(zip(boot.map.rises_mm, boot.map.height_mean_mm, strict=True))
    assert heights[0.0] < 1e-4 and heights[100.0] > 10 * heights[0.0]


def test_the_spread_scales_with_the_noise(noisy_boot, noisy_fits):
    small, large = noisy_boot[1.0], noisy_boot[4.0]
    for boot in (small, large):
        assert boot.fitted == B and boot.spread_mean_mm > 0.01
        assert boot.spread_p95_mm > boot.spread_mean_mm
    ratio = large.spread_mean_mm / small.spread_mean_mm
    assert 3.0 < ratio < 5.0, ratio  # linear in the noise: four times the noise, four times
    predicted = large.predicted_mean_mm / small.predicted_mean_mm
    assert 3.0 < predicted < 5.0, predicted
    # The expected touching error adds each target's own measurement to the fit's part.
    for boot in (small, large):
        assert boot.touching_mean_mm > boot.predicted_mean_mm


def test_a_seed_gives_the_report_bit_for_bit(noisy_fits, noisy_boot):
    result = noisy_fits[1.0]
    again = bootstrap(result, B)
    assert dataclasses.replace(again, seconds=0.0) == dataclasses.replace(noisy_boot[1.0],
                                                                          seconds=0.0)  # fmt: skip
    other = bootstrap(result, B, seed=result.seed + 1)
    assert other.spread_mean_mm != again.spread_mean_mm


def test_the_result_keeps_its_parameters_and_stores_the_bootstrap(noisy_fits, noisy_boot,
                                                                  tmp_path):  # fmt: skip
    result = noisy_fits[1.0]
    boot = noisy_boot[1.0]
    both = with_bootstrap(result, boot)
    assert both.stage1.params == result.stage1.params
    assert both.stage2.params == result.stage2.params
    path = tmp_path / "r.json"
    save_result(both, path)
    back = load_result(path).diagnostics.bootstrap
    assert isinstance(back, Bootstrap) and back == boot


def test_report_draws_the_workspace_error_map(noisy_fits, noisy_boot, tmp_path):
    result = with_bootstrap(noisy_fits[1.0], noisy_boot[1.0])
    path = tmp_path / "r.json"
    save_result(result, path)
    written = {p.name for p in write_report(path, tmp_path / "figs")}
    assert {"workspace_error_map.png", "workspace_error_map.svg"} <= written
    png = (tmp_path / "figs" / "workspace_error_map.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 20_000
    save_result(noisy_fits[1.0], tmp_path / "plain.json")  # no bootstrap: no map
    plain = {p.name for p in write_report(tmp_path / "plain.json", tmp_path / "plain")}
    assert "workspace_error_map.png" not in plain and len(plain) == len(written) - 2


@pytest.mark.parametrize(
    "value, needle",
    [("0", "must be 1 to 10,000 (got 0)"), ("10001", "must be 1 to 10,000 (got 10001)"),
     ("-3", "must be 1 to 10,000 (got -3)"), ("many", "not a whole number: 'many'")],
)  # fmt: skip
def test_the_command_line_refuses_a_bad_b_in_one_line(tmp_path, capsys, value, needle):
    ds = tmp_path / "d.toml"
    ds.write_text("")
    with pytest.raises(SystemExit) as e:
        main(["calibrate", str(ds), "--bootstrap", value])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "argument --bootstrap: " + needle in err, err


def test_the_command_line_refuses_a_bootstrap_of_a_recalibration(tmp_path, capsys):
    ds = tmp_path / "d.toml"
    ds.write_text("")
    code = main(["calibrate", str(ds), "--bootstrap", "5", "--prior", str(tmp_path / "o.json"),
                 "--refit", "pen"])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--bootstrap: not with --prior" in err, err
    assert "Traceback" not in err


# -- what a resample is ------------------------------------------------------------------


def three_captures():
    """The twin's landmarks seen from three capture poses (the views are the first's,
    which is all the resampling reads)."""
    ds = twin()
    first = ds.captures[0]
    caps = [Capture(first.hand_position_mm + [0.0, 0.0, rise], 10.0 * i, first.landmarks,
                    first.image_px, first.depth_mm)
            for i, rise in enumerate((0.0, 40.0, 80.0))]  # fmt: skip
    return ds.replace(captures=caps)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32), st.booleans())
def test_a_resample_is_a_dataset_of_the_same_design(seed, several):
    ds = three_captures() if several else twin()
    out = resample(ds, np.random.default_rng(seed))
    assert out.n_touches == ds.n_touches
    np.testing.assert_array_equal(out.tablet_px, ds.tablet_px)
    # Every touch is one of the originals, whole.
    rows = {tuple(np.r_[ds.hand_xy_mm[t], ds.hand_angle_deg[t], ds.touch_landmark[t]])
            for t in range(ds.n_touches)}  # fmt: skip
    for t in range(out.n_touches):
        assert tuple(np.r_[out.hand_xy_mm[t], out.hand_angle_deg[t], out.touch_landmark[t]]) in rows
    poses = {(tuple(c.hand_position_mm), c.hand_angle_deg) for c in ds.captures}
    assert {(tuple(c.hand_position_mm), c.hand_angle_deg) for c in out.captures} == poses
    np.testing.assert_array_equal(out.captures[0].hand_position_mm, ds.captures[0].hand_position_mm)
    if several:  # each picture's views drawn with replacement: as many as it had
        for c in ds.captures:
            same = [o for o in out.captures if o.hand_angle_deg == c.hand_angle_deg]
            assert sum(len(o.landmarks) for o in same) == len(c.landmarks)
            for o in same:  # a layer holds each view once
                assert len(set(o.landmarks.tolist())) == len(o.landmarks)
    else:
        assert out.captures == ds.captures
    assert out.n_rows > 0
