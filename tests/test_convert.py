"""``handeye-jax convert`` (v1 -> v2) and the version-2 file's text: same data, same fit."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

import handeye_jax as hj
from handeye_jax.cli import main

PAPER = Path(__file__).resolve().parent.parent / "data" / "paper2023.toml"
SMALL = hj.Settings(population=48, generations=40, restarts=1)


@pytest.fixture
def v1(tmp_path: Path) -> Path:
    path = tmp_path / "rig.toml"
    path.write_bytes(PAPER.read_bytes())
    return path


def _one_line_error(capsys, argv, *needles) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err
    return err


def test_convert_writes_v2_beside_that_loads_equal_and_calibrates_bit_for_bit(v1, capsys):
    before = v1.read_bytes()
    assert main(["convert", str(v1)]) == 0
    out = v1.with_name("rig.v2.toml")
    assert "rig.v2.toml" in capsys.readouterr().out
    assert v1.read_bytes() == before  # the original stays as it was
    assert tomllib.loads(out.read_text())["format"] == "handeye-jax.dataset/2"
    old, new = hj.load_dataset(v1), hj.load_dataset(out)
    assert (old.version, new.version) == (1, 2)
    assert new == old and len(new.captures) == 1 and new.n_touches == 9
    # The paper's implicit capture pose: phi = 0, i.e. hand angle -zero*sign = 90 deg.
    assert new.captures[0].hand_angle_deg == 90.0
    r_old, r_new = hj.calibrate(old, SMALL), hj.calibrate(new, SMALL)
    for a, b in ((r_old.stage1, r_new.stage1), (r_old.stage2, r_new.stage2)):
        assert a.params == b.params and a.F == b.F  # bit for bit, not approximately


def test_convert_in_place_needs_force_and_keeps_the_old_file(v1, capsys):
    before = v1.read_bytes()
    _one_line_error(capsys, ["convert", str(v1), "--out", str(v1)], "rig.toml", "--out",
                    "--force")  # fmt: skip
    assert v1.read_bytes() == before and sorted(p.name for p in v1.parent.iterdir()) == ["rig.toml"]
    assert main(["convert", str(v1), "--out", str(v1), "--force"]) == 0
    (backup,) = v1.parent.glob("rig.toml.*.bak")
    assert backup.read_bytes() == before
    assert str(backup.name) in capsys.readouterr().out
    assert hj.load_dataset(v1).version == 2 and hj.load_dataset(v1) == hj.load_dataset(backup)


def test_convert_refuses_an_existing_out_without_force(v1, tmp_path, capsys):
    out = tmp_path / "taken.toml"
    out.write_text("mine\n")
    _one_line_error(capsys, ["convert", str(v1), "--out", str(out)], "taken.toml", "--out",
                    "exists")  # fmt: skip
    assert out.read_text() == "mine\n"
    # --force replaces a file of any content, keeping it.
    (tmp_path / "old.toml").write_text("x = 1\n")
    assert main(["convert", str(v1), "--out", str(tmp_path / "old.toml"), "--force"]) == 0
    (backup,) = tmp_path.glob("old.toml.*.bak")
    assert backup.read_text() == "x = 1\n"


def test_an_already_v2_file_is_left_alone_with_exit_0(v1, capsys):
    assert main(["convert", str(v1)]) == 0
    v2 = v1.with_name("rig.v2.toml")
    text = v2.read_bytes()
    capsys.readouterr()
    assert main(["convert", str(v2), "--out", str(v2)]) == 0
    assert "already handeye-jax.dataset/2; nothing written" in capsys.readouterr().out
    assert v2.read_bytes() == text and not list(v1.parent.glob("*.bak"))
    assert not v1.with_name("rig.v2.v2.toml").exists()


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda t: t.replace("depth = 168.2", "depth = nan"), "landmarks[0].depth"),
        (lambda t: t.replace("fx = 617.7", "fx = -1.0"), "camera.fx"),
        (lambda t: t.replace('format = "handeye-jax.dataset/1"', 'format = "x"'), "format"),
    ],
)
def test_a_bad_v1_file_is_one_line_naming_it_and_nothing_is_written(v1, capsys, edit, field):
    v1.write_text(edit(v1.read_text()))
    _one_line_error(capsys, ["convert", str(v1)], "rig.toml", field)
    assert sorted(p.name for p in v1.parent.iterdir()) == ["rig.toml"]


def test_missing_file_and_unwritable_out(tmp_path, v1, capsys):
    _one_line_error(capsys, ["convert", str(tmp_path / "none.toml")], "none.toml")
    _one_line_error(capsys, ["convert", str(v1), "--out", str(tmp_path / "no" / "x.toml")],
                    "--out", "does not exist")  # fmt: skip
    _one_line_error(capsys, ["convert", str(v1), "--out", str(tmp_path)], "--out", "folder")


def test_api_refuses_an_existing_out_without_overwrite(v1, tmp_path):
    out = tmp_path / "o.toml"
    out.write_text("keep\n")
    with pytest.raises(hj.InputError, match="o.toml: exists"):
        hj.convert_to_v2(v1, out)
    assert out.read_text() == "keep\n"


def test_a_multi_capture_v2_dataset_saves_as_readable_text_and_loads_equal(tmp_path):
    paper = hj.load_dataset(PAPER)
    first = paper.captures[0]
    second = hj.Capture([330.0, -60.0, 370.0], 60.0, [4, 0, 8], first.image_px[[4, 0, 8]] + 0.5,
                        first.depth_mm[[4, 0, 8]] + 80.0)  # fmt: skip
    z = np.full(9, np.nan)
    z[2] = 105.25
    ds = paper.replace(captures=[first, second], hand_z_mm=z)
    path = tmp_path / "multi.toml"
    hj.save_dataset(ds, path)
    text = path.read_text()
    assert "    [338.0, 244.0]," in text  # one [u, v] a line
    assert text.count("[[captures]]") == 2 and text.count("hand_z = ") == 1
    back = hj.load_dataset(path)
    assert back == ds and back.version == 2


# -- plan: the recommended pictures ------------------------------------------------------------


def test_plan_adds_the_recommended_empty_captures_once(v1, capsys):
    assert main(["convert", str(v1), "--out", str(v1), "--force"]) == 0
    for backup in v1.parent.glob("*.bak"):
        backup.unlink()
    before = hj.load_dataset(v1)
    assert main(["plan", str(v1)]) == 0
    out = capsys.readouterr().out
    ds = hj.load_dataset(v1)
    first = before.captures[0]
    assert len(ds.captures) == 3 and ds.captures[0] == first
    for cap, rise, turn in zip(ds.captures[1:], (40.0, 80.0), (30.0, -30.0), strict=True):
        np.testing.assert_array_equal(cap.hand_position_mm, first.hand_position_mm + [0, 0, rise])
        assert cap.hand_angle_deg == first.hand_angle_deg + turn and cap.landmarks.size == 0
    assert "capture 2: hand at (320, -70, 370) mm, hand angle 60 deg (0 of 9 landmarks)" in out
    assert f"--dataset {v1} --capture 2" in out
    assert ds == before.replace(captures=ds.captures)  # nothing else changed
    (backup,) = v1.parent.glob("rig.toml.*.bak")
    assert hj.load_dataset(backup) == before
    assert main(["plan", str(v1)]) == 0  # planned already: nothing written
    assert "already holds them" in capsys.readouterr().out
    assert hj.load_dataset(v1) == ds and len(list(v1.parent.glob("*.bak"))) == 1


@pytest.mark.parametrize(
    ("extra", "needles"),
    [
        (["--rise-mm", "40", "--turn-deg", "30,-30"], ["--turn-deg: needs one turn per"]),
        (["--rise-mm", "40,nan"], ["--rise-mm", "finite"]),
        (["--turn-deg", "inf,1"], ["--turn-deg", "finite"]),
        (["--rise-mm", "40,x"], ["--rise-mm", "not a number: 'x'"]),
    ],
)
def test_plan_refuses_bad_options_in_one_line(v1, capsys, extra, needles):
    assert main(["convert", str(v1), "--out", str(v1), "--force"]) == 0
    capsys.readouterr()
    before = v1.read_bytes()
    try:
        code = main(["plan", str(v1), *extra])
    except SystemExit as e:  # argparse's own refusal of a malformed value
        code = e.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err
    assert v1.read_bytes() == before


def test_plan_refuses_a_version_1_dataset(v1, capsys):
    before = v1.read_bytes()
    _one_line_error(capsys, ["plan", str(v1)], "rig.toml: format", "handeye-jax convert")
    assert v1.read_bytes() == before and not list(v1.parent.glob("*.bak"))


def test_the_readmes_version_2_example_is_a_valid_dataset(tmp_path):
    readme = (PAPER.parents[1] / "docs" / "file-formats.md").read_text()
    blocks = [b for b in readme.split("```toml\n")[1:] if "handeye-jax.dataset/2" in b[:60]]
    assert len(blocks) == 1
    path = tmp_path / "example.toml"
    path.write_text(blocks[0].split("```")[0])
    ds = hj.load_dataset(path)
    assert ds.version == 2 and ds.n_landmarks == 3 and len(ds.captures) == 1
    np.testing.assert_array_equal(ds.captures[0].landmarks, [0, 1, 2])
    assert ds.hand_z_mm[0] == 105.0 and ds.touch_landmark.tolist() == [0]
