"""``plan`` checks each planned picture: where it will show each landmark by the rig's
approximate model, checked on twins (issue 23, section 4)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import handeye_jax as hj
from handeye_jax import draw_truth
from handeye_jax.cli import main

PAPER = Path(__file__).resolve().parent.parent / "data" / "paper2023.toml"
MOUNT = ("xc", "yc", "alpha_c", "beta_c", "gamma_c")


def _twin_dataset(truth) -> hj.Dataset:
    """What a twin's first picture shows, exactly, as a dataset (no touches needed here)."""
    uv, depth = truth.project(truth.landmarks_tablet_px)
    c, n = truth.camera_px, len(uv)
    first = hj.Capture(np.array(truth.capture_position_mm), truth.capture_angle_deg,
                       np.arange(n), uv, depth)  # fmt: skip
    return hj.Dataset(
        name="twin", camera=hj.Camera(c["fx"], c["fy"], c["cx"], c["cy"]),
        tablet_ppi=truth.ppi, tablet_scale=truth.scale,
        hand_angle_zero_deg=truth.hand_angle_zero_deg, hand_angle_sign=truth.hand_angle_sign,
        search={}, tablet_px=truth.landmarks_tablet_px, hand_xy_mm=np.zeros((n, 2)),
        hand_angle_deg=np.zeros(n), touch_error_px=np.zeros((n, 2)), captures=[first],
        touch_landmark=np.arange(n),
    )  # fmt: skip


def _poses(truth, rng, k=5):
    for _ in range(k):
        rise, turn = rng.uniform(0, 150), rng.uniform(-60, 60)
        yield np.array(truth.capture_position_mm) + [0, 0, rise], truth.capture_angle_deg + turn


def test_through_the_true_mount_the_planned_picture_is_the_twins():
    """Every hand-angle convention (seeds 1-4 draw the four), any rise and turn: to 1e-6 px."""
    rng = np.random.default_rng(1)
    for seed in range(1, 9):
        truth = draw_truth(seed)
        ds = _twin_dataset(truth)
        for position, angle in _poses(truth, rng):
            want, _ = truth.at_capture(position, angle).project(truth.landmarks_tablet_px)
            view = hj.planned_view(ds, position, angle, truth.image_size_px,
                                   mount={k: truth.model[k] for k in MOUNT})  # fmt: skip
            np.testing.assert_allclose(view.image_px, want, rtol=0, atol=1e-6)


def test_a_landmark_called_in_view_is_in_the_twins_picture():
    """What ``plan`` claims: a landmark in view for every mount within the spread is in the
    picture (twins' mounts lie within it); the approximate model errs only by calling some
    near the edge."""
    rng = np.random.default_rng(2)
    said = {"in view": 0, "outside": 0, "at risk": 0}
    for seed in range(1, 31):
        truth = draw_truth(seed)
        ds = _twin_dataset(truth)
        w, h = truth.image_size_px
        for position, angle in _poses(truth, rng):
            uv, z = truth.at_capture(position, angle).project(truth.landmarks_tablet_px)
            inside = (z > 0) & np.all((uv >= 0) & (uv <= [w - 1, h - 1]), axis=1)
            view = hj.planned_view(ds, position, angle, (w, h))
            called = set(range(len(uv))) - set(view.outside) - set(view.at_risk)
            assert all(inside[m] for m in called), (seed, position, angle)
            said["in view"] += len(called)
            said["outside"] += len(view.outside)
            said["at risk"] += len(view.at_risk)
    assert min(said.values()) > 10, said  # every verdict was given, often


@pytest.fixture
def v2(tmp_path: Path) -> Path:
    path = tmp_path / "rig.toml"
    path.write_bytes(PAPER.read_bytes())
    assert main(["convert", str(path), "--out", str(path), "--force"]) == 0
    return path


def test_plan_names_the_landmarks_a_planned_picture_loses(v2, capsys):
    capsys.readouterr()
    argv = ["plan", str(v2), "--rise-mm", "5,80", "--turn-deg=45,-45", "--image-size-px", "640,480"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "Each planned picture shows" not in out and "each with every landmark" not in out
    lines = out.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("  capture 1: "))
    assert lines[at + 1].startswith("    landmarks 2, 8 outside the picture;"), out
    assert "Checked against a 640 x 480 px picture, by the rig's approximate model" in out
    assert len(hj.load_dataset(v2).captures) == 3  # planned all the same: the operator decides


def test_plan_says_every_landmark_is_in_view_only_when_checked(v2, capsys):
    capsys.readouterr()
    assert main(["plan", str(v2), "--rise-mm", "80", "--turn-deg=-30",
                 "--image-size-px", "640,480"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "Each planned picture shows every landmark (a 640 x 480 px picture" in out
    assert "outside" not in out and "near its edge" not in out
    # a first capture that shows two landmarks places no tablet: nothing is claimed
    ds = hj.load_dataset(v2)
    first = ds.captures[0]
    few = hj.Capture(first.hand_position_mm, first.hand_angle_deg, first.landmarks[:2],
                     first.image_px[:2], first.depth_mm[:2])  # fmt: skip
    hj.save_dataset(ds.replace(captures=[few, *ds.captures[1:], first]), v2)
    assert main(["plan", str(v2), "--rise-mm", "40", "--turn-deg", "10"]) == 0
    out = capsys.readouterr().out
    assert "Each planned picture shows" not in out
    assert "Not checked whether each picture shows every landmark: capture 0 shows 2" in out


def test_plan_refuses_a_bad_picture_size_in_one_line(v2, capsys):
    before = v2.read_bytes()
    for size in ("640,4.5", "0,480", "640,-480", "100000,100000", "640"):
        with pytest.raises(SystemExit) as e:
            main(["plan", str(v2), "--image-size-px", size])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "argument --image-size-px: needs 2" in err[0], err
    assert v2.read_bytes() == before
