"""``handeye-jax report``: every figure in PNG and SVG, one-line errors that write nothing."""

import json

import pytest

from handeye_jax.cli import main
from handeye_jax.report import FIGURES, FORMATS
from tests.test_cli import FAST, PAPER

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def result_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("rep") / "paper.json"
    assert main(["calibrate", str(PAPER), "--out", str(out), *FAST]) == 0
    return out


def _check_figures(folder):
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted(f"{f}.{e}" for f in FIGURES for e in FORMATS)
    for f in FIGURES:
        assert (folder / f"{f}.png").read_bytes()[:8] == PNG_SIGNATURE
        assert b"<svg" in (folder / f"{f}.svg").read_bytes()[:2000]


def test_report_writes_every_figure(result_file, tmp_path, capsys):
    out = tmp_path / "figs"
    assert main(["report", str(result_file), "--out", str(out)]) == 0
    _check_figures(out)
    assert str(out) in capsys.readouterr().out
    assert main(["report", str(result_file)]) == 0  # default: next to the result
    _check_figures(result_file.with_name("paper_report"))


def test_report_of_an_old_result_needs_the_dataset(result_file, tmp_path, capsys):
    doc = json.loads(result_file.read_text())
    del doc["observations"], doc["diagnostics"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(doc))
    out = tmp_path / "figs"
    assert main(["report", str(old), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "observations" in err and "--dataset" in err
    assert not out.exists()
    assert main(["report", str(old), "--out", str(out), "--dataset", str(PAPER)]) == 0
    _check_figures(out)


def test_bad_inputs_are_one_line_and_keep_what_was_there(result_file, tmp_path, capsys):
    out = tmp_path / "figs"
    out.mkdir()
    (out / "loo.png").write_bytes(b"precious")
    bad = tmp_path / "bad.json"
    doc = json.loads(result_file.read_text())
    doc["observations"]["depth_mm"][2] = "deep"
    bad.write_text(json.dumps(doc))
    assert main(["report", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "observations.depth_mm[2]" in err
    assert (out / "loo.png").read_bytes() == b"precious"
    assert sorted(p.name for p in out.iterdir()) == ["loo.png"]
    assert main(["report", str(tmp_path / "missing.json"), "--out", str(out)]) == 2
    assert "missing.json" in capsys.readouterr().err
    assert main(["report", str(result_file), "--out", str(tmp_path / "no" / "dir")]) == 2
    assert "does not exist" in capsys.readouterr().err


BAD_LOSS_ARGS = [["--loss", "l2"], ["--loss-scale-mm", "-1"], ["--loss-scale-mm", "nan"],
                 ["--loss-scale-mm", "x"]]  # fmt: skip


@pytest.mark.parametrize("args", BAD_LOSS_ARGS)
def test_bad_loss_arguments_are_one_line(args, capsys):
    with pytest.raises(SystemExit) as e:
        main(["calibrate", str(PAPER), *args])
    assert e.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_no_diagnostics_leaves_them_out(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["calibrate", str(PAPER), "--no-diagnostics", "--out", str(out), *FAST]) == 0
    text = capsys.readouterr().out
    assert "convention check" not in text and "leave-one-out" not in text
    assert "diagnostics" not in json.loads(out.read_text())
