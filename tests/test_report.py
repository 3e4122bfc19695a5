"""``handeye-jax report``: every figure in PNG and SVG, one-line errors that write nothing."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from handeye_jax import load_result
from handeye_jax._core import REPORT_FIGURES as FIGURES
from handeye_jax._core import REPORT_FORMATS as FORMATS
from handeye_jax.cli import main
from tests.common import FAST, PAPER

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="session")
def result_file(paper_result_file):
    return paper_result_file


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


def test_report_writes_next_to_the_result_and_nothing_on_stderr(result_file, tmp_path):
    # Matplotlib with a config folder it cannot write (it logs a warning) and the user's
    # matplotlibrc naming a font without "−" and "×" (a warning per glyph).
    rc = tmp_path / "matplotlibrc"
    rc.write_text("font.family: cmr10\n")
    # TMPDIR: where Matplotlib makes its temporary config folder instead.
    env = dict(os.environ, MPLCONFIGDIR=str(rc / "not-a-folder"), MATPLOTLIBRC=str(rc),
               TMPDIR=str(tmp_path))  # fmt: skip
    p = subprocess.run([sys.executable, "-m", "handeye_jax.cli", "report", str(result_file)],
                       capture_output=True, text=True, env=env)  # fmt: skip
    assert (p.returncode, p.stderr) == (0, "")
    folder = result_file.with_name("paper_report")  # the default: next to the result
    assert p.stdout == f"12 figures (PNG and SVG) written to {folder}\n"
    _check_figures(folder)


def test_report_of_an_old_result_needs_the_dataset(result_file, tmp_path, capsys):
    doc = json.loads(result_file.read_text())
    del doc["data"], doc["diagnostics"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(doc))
    out = tmp_path / "figs"
    assert main(["report", str(old), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "data: missing" in err and "--dataset" in err
    assert not out.exists()
    assert main(["report", str(old), "--out", str(out), "--dataset", str(PAPER)]) == 0
    _check_figures(out)


def test_bad_inputs_are_one_line_and_keep_what_was_there(result_file, tmp_path, capsys):
    out = tmp_path / "figs"
    out.mkdir()
    (out / "loo.png").write_bytes(b"precious")
    bad = tmp_path / "bad.json"
    doc = json.loads(result_file.read_text())
    doc["data"]["landmarks"][2]["depth"] = "deep"
    bad.write_text(json.dumps(doc))
    assert main(["report", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "data.landmarks[2].depth" in err
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
    argv = ["calibrate", str(PAPER), "--no-diagnostics", "--verbose", "--out", str(out), *FAST]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "convention check" not in text and "held-out F" not in text
    assert "expected touching error: not computed (diagnostics skipped)" in text
    assert "diagnostics" not in json.loads(out.read_text())


# -- what the figures show ---------------------------------------------------------------


@pytest.fixture(scope="module")
def figures(result_file):
    from handeye_jax import render

    figs = render(load_result(result_file))
    for fig in figs.values():
        fig.draw_without_rendering()  # layout and limits as in the saved files
    return figs


def test_the_leave_one_out_figure_carries_the_summarys_verdict(figures, result_file):
    from handeye_jax import format_summary

    r = load_result(result_file)
    title = figures["loo"]._suptitle.get_text()
    e = r.diagnostics.expected
    assert f"verdict: deploy stage {r.deploy_stage}" in title
    assert f"{e.mean_mm:.2g} mm mean, {e.p95_mm:.2g} mm 95th percentile" in title
    assert f"VERDICT  deploy stage {r.deploy_stage}" in format_summary(r)  # the same stage
    assert f"{e.mean_mm:.2g} mm mean, {e.p95_mm:.2g} mm 95th percentile" in format_summary(r)


def _inside(inner, outer, tol_px=1.0):
    return (inner.x0 >= outer.x0 - tol_px and inner.x1 <= outer.x1 + tol_px
            and inner.y0 >= outer.y0 - tol_px and inner.y1 <= outer.y1 + tol_px)  # fmt: skip


def test_both_stages_draw_errors_at_one_scale_and_say_which_way_they_point(figures, result_file):
    from matplotlib.quiver import Quiver

    from handeye_jax.report._figures import chain_data

    scales = []
    for stage, data in zip((1, 2), chain_data(load_result(result_file)), strict=True):
        fig = figures[f"chains_stage{stage}"]
        preds, targets = (data.image_xy, data.hand_pred_xy), (data.tablet_xy, data.hand_target_xy)
        for ax, pred, target in zip(fig.axes, preds, targets, strict=True):
            (q,) = [c for c in ax.collections if isinstance(c, Quiver)]
            drawn = np.hypot(q.U, q.V)
            error = np.linalg.norm(pred - target, axis=1)
            scales.append(drawn[error > 0.05] / error[error > 0.05])
            label = next(t.get_text() for t in ax.get_legend().get_texts() if "×" in t.get_text())
            assert "from ○ to •" in label and "×10" in label
    scales = np.concatenate(scales)
    np.testing.assert_allclose(scales, 10.0, rtol=1e-9)


def test_the_length_key_lies_inside_its_panel(figures):
    from matplotlib.quiver import QuiverKey
    from matplotlib.transforms import Bbox

    for stage in (1, 2):
        for ax in figures[f"chains_stage{stage}"].axes:
            (key,) = [a for a in ax.artists if isinstance(a, QuiverKey)]
            v = key.vector  # the arrow: a polygon in display units around its offset
            at = v.get_offset_transform().transform(v.get_offsets())
            arrow = Bbox.null()
            arrow.update_from_data_xy(v.get_transform().transform(v.get_paths()[0].vertices) + at)
            label = key.text.get_window_extent()
            assert _inside(arrow, ax.bbox) and _inside(label, ax.bbox), (stage, arrow, ax.bbox)
            assert arrow.width > 20  # a key one can read: 1 mm drawn ×10 is at least 20 px


def test_no_legend_covers_a_bar(result_file, tmp_path):
    from handeye_jax.report._figures import fig_loo, fig_residuals

    # Every landmark's error about the same: no free corner for a legend inside the panels.
    doc = json.loads(result_file.read_text())
    for stage in ("stage1", "stage2"):
        for r in doc[stage]["residuals_mm"]:
            r["image_vs_tablet_mm"], r["hand_mm"] = 1.9 + 0.01 * r["m"], 2.0
    result = _load_result_from(doc, tmp_path / "flat.json")
    for fig in (fig_residuals(result), fig_loo(result)):
        fig.draw_without_rendering()
        legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend())]
        bars = [p.get_window_extent() for ax in fig.axes for p in ax.patches if p.get_height()]
        assert legends and len(bars) >= 18
        for legend in legends:
            box = legend.get_window_extent()
            assert not any(box.overlaps(b) for b in bars)


def _load_result_from(doc, path):
    path.write_text(json.dumps(doc))
    return load_result(path)


def _label_boxes(ax):
    ticks = ax.yaxis.get_major_ticks() + ax.yaxis.get_minor_ticks()
    lo, hi = sorted(ax.get_ylim())
    shown = [t.label1 for t in ticks if lo <= t.get_loc() <= hi]
    return [t.get_window_extent() for t in shown if t.get_visible() and t.get_text()]


@pytest.mark.parametrize("decades", [0.3, 0.6, 0.8, 1.3, 1.9, 3.0, 9.0])
def test_log_axis_labels_never_overlap(result_file, tmp_path, decades):
    from handeye_jax.report._figures import fig_convergence

    doc = json.loads(result_file.read_text())
    for stage in ("stage1", "stage2"):
        best = np.geomspace(1.6 * 10**decades, 1.6, 400).tolist()
        doc[stage]["convergence"] = {"best_F": best, "median_F": best[63::64],
                                     "median_generation": list(range(64, 400, 64))}  # fmt: skip
        doc[stage]["F"] = 1.6
    fig = fig_convergence(_load_result_from(doc, tmp_path / "r.json"))
    fig.draw_without_rendering()
    for ax in fig.axes:
        boxes = _label_boxes(ax)
        assert len(boxes) >= 2, "a log axis needs at least two numbers to be read"
        for i, a in enumerate(boxes):
            assert not any(a.overlaps(b) for b in boxes[i + 1 :]), [
                t.get_text() for t in ax.get_yticklabels()
            ]


@pytest.mark.parametrize("corner", ["top left", "top right", "bottom left", "bottom right",
                                    "right edge", "top edge"])  # fmt: skip
def test_overlay_labels_stay_inside_the_picture(corner):
    from handeye_jax.vision import overlay_image

    h, w = 120, 160
    u, v = {"top left": (3, 3), "top right": (w - 4, 3), "bottom left": (3, h - 4),
            "bottom right": (w - 4, h - 4), "right edge": (w - 10, 60),
            "top edge": (80, 5)}[corner]  # fmt: skip
    white = np.full((h, w), 255, np.uint8)

    def label_pixels(uv, text):
        with_label = overlay_image(white, np.array([uv], float), [text])
        without = overlay_image(white, np.array([uv], float), [""])
        return int(np.any(with_label != without, axis=2).sum())

    text = "8: 169 mm"
    whole = label_pixels((w / 2, h / 2), text)  # where nothing can clip it
    assert whole > 50
    assert label_pixels((u, v), text) >= 0.97 * whole  # a pixel or two may fall on the circle
