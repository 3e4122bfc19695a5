"""Outputs: checked before the work, written all or nothing, never over an input.

Every failure is exit 2 with one line naming the file and option; whatever was in the folders
before is byte-identical afterwards, and no temporary or partial file is left behind.
"""

import importlib
import struct
import zlib
from pathlib import Path

import pytest

import handeye_jax._core._atomic as _atomic
from handeye_jax import PRESETS, InputError, draw_truth, simulate, write_twin
from handeye_jax.cli import main
from tests.common import FAST, PAPER

# The folder the command line takes calibrate from.
CALIBRATE = importlib.import_module("handeye_jax.calibration")
UNWRITABLE = ["/sys", "/proc", "FILE"]  # folders no one can write in; FILE: a regular file


@pytest.fixture(scope="session")
def result_file(paper_result_file):
    return paper_result_file


@pytest.fixture(scope="module")
def twin_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("twin")
    write_twin(simulate(draw_truth(3), PRESETS["paper"], 3, n_heldout=3), folder)
    return folder


def _snapshot(*folders):
    """Every file (and folder) under ``folders`` with its bytes."""
    out = {}
    for folder in folders:
        for p in sorted(Path(folder).rglob("*")):
            out[p] = None if p.is_dir() else p.read_bytes()
    return out


def _fails(capsys, argv, *needles):
    """``main(argv)`` is 2 with one stderr line holding every needle; returns that line."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "internal error" not in err and ".tmp" not in err, err
    for n in needles:
        assert n in err, err
    return err


def _unwritable(where, tmp_path, name):
    if where.startswith("FILE"):
        (tmp_path / "afile").write_text("a file, not a folder")
        return str(tmp_path / "afile" / name)
    return f"{where}/{name}"


def _detect(twin_dir, dataset, *more):
    return ["detect", str(twin_dir / "capture.png"), str(twin_dir / "depth.png"),
            "--dataset", str(dataset), *more]  # fmt: skip


@pytest.fixture
def no_fit(monkeypatch):
    def fit(*args, **kwargs):
        raise AssertionError("the fit ran before the output was checked")

    monkeypatch.setattr(CALIBRATE, "calibrate", fit)


# -- 1: an unwritable output is refused before the work -----------------------------------


@pytest.mark.parametrize("where", UNWRITABLE)
def test_calibrate_refuses_an_unwritable_out_before_the_fit(where, tmp_path, capsys, no_fit):
    out = _unwritable(where, tmp_path, "r.json")
    before = _snapshot(tmp_path)
    _fails(capsys, ["calibrate", str(PAPER), "--out", out, *FAST], out, "--out", "cannot write")
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize("where", UNWRITABLE)
def test_predict_and_report_refuse_an_unwritable_out(where, result_file, tmp_path, capsys):
    pts = tmp_path / "p.csv"
    pts.write_text("u,v,depth,hand_angle\n338,244,169.2,90\n")
    out = _unwritable(where, tmp_path, "o.csv")
    before = _snapshot(tmp_path, result_file.parent)
    _fails(capsys, ["predict", str(result_file), str(pts), "--out", out], out, "--out")
    rep = _unwritable(where, tmp_path, "rep")
    _fails(capsys, ["report", str(result_file), "--out", rep], rep, "--out", "cannot write")
    assert _snapshot(tmp_path, result_file.parent) == before


def test_a_failed_final_write_names_the_users_file(result_file, tmp_path, capsys, monkeypatch):
    pts = tmp_path / "p.csv"
    pts.write_text("u,v,depth,hand_angle\n338,244,169.2,90\n")
    before = _snapshot(tmp_path)

    def denied(path, data):
        raise PermissionError(13, "Permission denied", str(path.parent / ".o.csv.x1y2.tmp"))

    monkeypatch.setattr(_atomic, "_write_temp", denied)
    out = tmp_path / "o.csv"
    err = _fails(capsys, ["predict", str(result_file), str(pts), "--out", str(out)],
                 f"{out}: --out: cannot write: Permission denied")  # fmt: skip
    assert "x1y2" not in err
    assert _snapshot(tmp_path) == before


def test_calibrate_final_write_failure_is_one_line(result_file, tmp_path, capsys, monkeypatch):
    from handeye_jax import load_result

    monkeypatch.setattr(CALIBRATE, "calibrate", lambda *a, **k: load_result(result_file))

    def full(path, data):
        raise OSError(28, "No space left on device", str(path.parent / ".r.json.zz.tmp"))

    monkeypatch.setattr(_atomic, "_write_temp", full)
    out = tmp_path / "r.json"
    _fails(capsys, ["calibrate", str(PAPER), "--out", str(out), *FAST],
           f"{out}: --out: cannot write: No space left on device")  # fmt: skip
    assert list(tmp_path.iterdir()) == []


def test_detect_refuses_an_unwritable_overlay_before_detecting(twin_dir, tmp_path, capsys):
    out, overlay = tmp_path / "x.toml", "/sys/o.png"
    argv = _detect(twin_dir, twin_dir / "dataset.toml", "--out", str(out), "--overlay", overlay)
    before = _snapshot(twin_dir, tmp_path)
    _fails(capsys, argv, overlay, "--overlay", "cannot write")
    assert _snapshot(twin_dir, tmp_path) == before


def test_tablet_refuses_unwritable_or_input_trials(tmp_path, capsys, monkeypatch):
    def serve(*args, **kwargs):
        raise AssertionError("the server started before --trials was checked")

    monkeypatch.setattr("handeye_jax.tablet.serve", serve)
    _fails(capsys, ["tablet", "--dataset", str(PAPER), "--trials", "/sys/t.json", "--port", "0"],
           "/sys/t.json", "--trials")  # fmt: skip
    ds = tmp_path / "d.toml"
    ds.write_bytes(PAPER.read_bytes())
    argv = ["tablet", "--dataset", str(ds), "--trials", str(ds), "--port", "0"]
    _fails(capsys, argv, "d.toml", "--trials", "is the input")
    assert ds.read_bytes() == PAPER.read_bytes()


# -- 2, 3: a folder of outputs is written all or nothing ----------------------------------


def test_report_changes_nothing_when_one_figure_cannot_be_written(result_file, tmp_path, capsys):
    out = tmp_path / "reppart"
    (out / "loo.svg").mkdir(parents=True)
    (out / "fig3_landmarks.png").write_text("SENTINEL")
    before = _snapshot(out)
    _fails(capsys, ["report", str(result_file), "--out", str(out)], "loo.svg", "is a folder")
    assert _snapshot(out) == before


def test_folder_write_is_undone_when_a_replace_fails(tmp_path, monkeypatch):
    folder = tmp_path / "figs"
    folder.mkdir()
    (folder / "a.png").write_text("old a")
    (folder / "c.png").write_text("old c")
    before = _snapshot(folder)
    real = _atomic.os.replace
    calls = []

    def flaky(src, dst):
        calls.append(dst)
        if len(calls) == 3:  # a and b are in place by now
            raise OSError(5, "Input/output error")
        real(src, dst)

    monkeypatch.setattr(_atomic.os, "replace", flaky)
    files = {n: f"new {n}".encode() for n in ("a.png", "b.png", "c.png")}
    with pytest.raises(InputError, match=r"c\.png: --out: cannot write: Input/output error"):
        _atomic.write_folder_atomic(folder, files, "--out")
    monkeypatch.undo()
    assert _snapshot(folder) == before
    new = tmp_path / "new"
    monkeypatch.setattr(_atomic.os, "replace", flaky)
    calls.clear()
    with pytest.raises(InputError):
        _atomic.write_folder_atomic(new, files)
    assert not new.exists()  # made for the write, removed again


def test_simulate_changes_nothing_when_one_file_cannot_be_written(tmp_path, capsys):
    out = tmp_path / "simpart"
    (out / "heldout.csv").mkdir(parents=True)
    (out / "dataset.toml").write_text("SENTINEL")
    (out / "truth.json").write_text("SENTINEL")
    before = _snapshot(out)
    _fails(capsys, ["simulate", str(out), "--seed", "3"], "heldout.csv", "is a folder")
    assert _snapshot(out) == before


def test_simulate_refuses_a_truth_it_would_overwrite(tmp_path, capsys):
    out = tmp_path / "tw"
    out.mkdir()
    truth = out / "truth.json"
    truth.write_text(draw_truth(5).to_json())
    before = _snapshot(out)
    _fails(capsys, ["simulate", str(out), "--truth", str(truth)], "truth.json", "is the input")
    assert _snapshot(out) == before


def test_simulate_refuses_an_unwritable_folder(tmp_path, capsys):
    _fails(capsys, ["simulate", "/sys/twin"], "/sys/twin", "cannot write")


# -- 4: detect writes its overlay last --------------------------------------------------------


def test_detect_keeps_the_overlay_when_the_dataset_cannot_be_written(twin_dir, tmp_path, capsys):
    overlay = tmp_path / "ov_sentinel.png"
    overlay.write_text("SENTINEL")
    before = _snapshot(twin_dir, tmp_path)
    argv = _detect(twin_dir, twin_dir / "dataset.toml", "--out", "/sys/n.toml",
                   "--overlay", str(overlay))  # fmt: skip
    _fails(capsys, argv, "/sys/n.toml", "--out")
    assert _snapshot(twin_dir, tmp_path) == before


def test_detect_discards_the_overlay_when_the_dataset_write_fails(
    twin_dir, tmp_path, capsys, monkeypatch
):
    def refuse(ds, path):
        raise InputError(path, "", "cannot write: No space left on device")

    monkeypatch.setattr("handeye_jax.data.save_dataset", refuse)  # as detect finds it
    (tmp_path / "ov.png").write_text("SENTINEL")
    before = _snapshot(tmp_path)
    argv = _detect(twin_dir, twin_dir / "dataset.toml", "--out", str(tmp_path / "new.toml"),
                   "--overlay", str(tmp_path / "ov.png"))  # fmt: skip
    _fails(capsys, argv, "new.toml", "No space left")
    assert _snapshot(tmp_path) == before
    monkeypatch.undo()
    assert main(argv) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.toml", "ov.png"]
    assert (tmp_path / "ov.png").read_bytes()[:4] == b"\x89PNG"


def test_detect_refuses_an_overlay_over_an_input(twin_dir, tmp_path, capsys):
    before = _snapshot(twin_dir)
    for victim in ("capture.png", "dataset.toml"):
        argv = _detect(twin_dir, twin_dir / "dataset.toml", "--overlay", str(twin_dir / victim))
        _fails(capsys, argv, victim, "--overlay")
    argv = _detect(twin_dir, twin_dir / "dataset.toml", "--out", str(twin_dir / "depth.png"))
    _fails(capsys, argv, "depth.png", "--out", "is the input")
    assert _snapshot(twin_dir) == before


# -- 5, 6: broken pictures are one line -------------------------------------------------------


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _broken_pngs(twin_dir, folder):
    cap = (twin_dir / "capture.png").read_bytes()
    idat = cap.index(b"IDAT")
    corrupt = bytearray(cap)
    corrupt[idat + 200 : idat + 264] = bytes(64)
    header = struct.pack(">IIBBBBB", 100000, 100000, 8, 0, 0, 0, 0)  # 8-bit grey
    huge = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header)
            + _chunk(b"IDAT", zlib.compress(bytes(1000))) + _chunk(b"IEND", b""))  # fmt: skip
    files = {"truncated.png": cap[: len(cap) // 2], "idat_corrupt.png": bytes(corrupt),
             "huge_header.png": huge}  # fmt: skip
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return [folder / name for name in files]


@pytest.mark.parametrize("as_depth", [False, True])
def test_broken_pngs_are_one_line_naming_the_file(twin_dir, tmp_path, capfd, as_depth):
    out = tmp_path / "sentinel.toml"
    out.write_text("SENTINEL")
    for bad in _broken_pngs(twin_dir, tmp_path):
        before = _snapshot(tmp_path)
        images = [twin_dir / "capture.png", bad] if as_depth else [bad, twin_dir / "depth.png"]
        argv = ["detect", *map(str, images), "--dataset", str(twin_dir / "dataset.toml"),
                "--out", str(out)]  # fmt: skip
        assert main(argv) == 2
        err = capfd.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert err.startswith("handeye-jax: error: ") and f"{bad}: cannot read image" in err
        if bad.name == "huge_header.png":
            assert "100000x100000" in err
        assert _snapshot(tmp_path) == before
