"""Files believed without checking (issue 23, section 2): a forged result, an edited or
foreign prior, a FIFO given as a result, a negative seed.

The forgeries recompute the content digest, as anyone editing a file can: what refuses them is
the agreement of a result's parts (frames, parameters, rig, data, residuals) and the rig's reach,
checked by ``predict`` with NumPy alone and by every other reader through ``load_result``.

The fixture ``folder`` (test_result_input's): a result the toolkit wrote of the paper's data,
``folder/good.json``, and a points CSV, ``folder/pts.csv``.
"""
# ruff: noqa: F811  (test functions take the imported fixture ``folder`` as an argument)

from __future__ import annotations

import json
import os
import re
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from frames_cases import cases, run_without_jax
from hypothesis import given, settings
from hypothesis import strategies as st

from handeye_jax import (
    InputError,
    Predictor,
    calibrate,
    chain_points,
    load_dataset,
    load_result,
    save_result,
)
from handeye_jax._core import DIGEST_KEY, document_digest
from handeye_jax.cli import main
from handeye_jax.data import Camera
from handeye_jax.models import AffinePair, model_registry
from handeye_jax.problem import stage1_errors, stage2_errors
from handeye_jax.robot import stored_result
from tests.common import FAST, FAST_SETTINGS, PAPER
from tests.test_result_input import JSON_VALUES, _paths, _set, folder  # noqa: F401


def _with_digest(doc: dict) -> str:
    """The document as the writer would write it: its digest recomputed."""
    doc = {k: v for k, v in doc.items() if k != DIGEST_KEY}
    doc[DIGEST_KEY] = document_digest(doc)
    return json.dumps(doc, indent=2)


def _edited(folder: Path, name: str, edit) -> Path:
    doc = json.loads((folder / "good.json").read_text())
    edit(doc)
    path = folder / f"{name}.json"
    path.write_text(_with_digest(doc))
    return path


def _residuals(errors) -> list[dict]:
    e1, e2 = np.asarray(errors.image_vs_tablet), np.asarray(errors.hand)
    return [{"m": m, "image_vs_tablet_xy_mm": e1[m].tolist(),
             "image_vs_tablet_mm": float(np.linalg.norm(e1[m])), "hand_xy_mm": e2[m].tolist(),
             "hand_mm": float(np.linalg.norm(e2[m]))} for m in range(len(e1))]  # fmt: skip


def _perfect_forgery(folder: Path, fx: float, sx1: float) -> Path:
    """The issue's forgery made consistent everywhere, by the toolkit's own writer: the data,
    the rig, the parameters, the frames, the centres and every residual agree with fx and
    Sx1 (as if the fit had found Sx1 on data taken with fx)."""
    good = load_result(folder / "good.json")
    c = good.data.camera
    data = good.data.replace(camera=Camera(fx, c.fy_px, c.cx_px, c.cy_px))
    obs = data.observations()
    correction = AffinePair.from_dict({**good.stage2.params, "Sx1": sx1})
    points = chain_points(good.model, obs)
    e2, centres = stage2_errors(correction, points, obs.centre_index)
    forged = replace(
        good, data=data, rig=obs.rig, correction=correction, centres_mm=np.asarray(centres),
        stage1=replace(good.stage1, residuals_mm=_residuals(stage1_errors(points))),
        stage2=replace(good.stage2, params=correction.to_dict(), residuals_mm=_residuals(e2)),
        diagnostics={},
    )  # fmt: skip
    path = folder / "perfect.json"
    save_result(forged, path)
    return path


def _put(*keys_and_value):
    *keys, last, value = keys_and_value

    def edit(doc):
        for k in keys:
            doc = doc[k]
        doc[last] = value(doc[last]) if callable(value) else value

    return edit


def _both(*edits):
    def edit(doc):
        for e in edits:
            e(doc)

    return edit


#: name: (edit of good.json, the field the refusal names, words of the message).
FORGERIES = {
    # the issue's: fx = 1 in the rig and the frames, Sx1 = 999 in the parameters and the
    # frames: both agree with each other, not with the data
    "issue": (_both(_put("rig", "camera_px", "fx", 1.0), _put("frames", "camera_px", "fx", 1.0),
                    _put("stage2", "params", "Sx1", 999.0),
                    _put("frames", "stage2", "A1", "Sx", 999.0)),
              "rig.camera_px.fx", "is 1 px but the data it was fitted on say 617.7 px"),
    "frames only": (_put("frames", "camera_px", "fx", 1.0), "frames",
                    "its camera_px is [1, 617.7"),
    "parameters only": (_put("stage1", "params", "xp", lambda v: v + 5.0), "frames",
                        "disagrees with the parameters"),
    # the pen moved 5 mm in the parameters and the frames alike: the fit's residuals disagree
    "parameters and frames": (
        _both(_put("stage1", "params", "xp", lambda v: v + 5.0),
              _put("frames", "pen_tip", "t_hand_pen", "mm", 0, lambda v: v + 5.0)),
        r"stage1\.residuals_mm\[\d\]\.hand_xy_mm", "but the parameters give"),
    # ... the rig, the frames and the data's camera too (fx = 1 the data's own check
    # refuses: no picture is 180 degrees wide): the residuals the fit recorded disagree
    "and the data": (
        _both(_put("rig", "camera_px", "fx", 400.0), _put("frames", "camera_px", "fx", 400.0),
              _put("data", "camera", "fx", 400.0)),
        r"stage1\.residuals_mm\[\d\]\.image_vs_tablet_xy_mm", "but the parameters give"),
}  # fmt: skip


def _one_line(err: str, path: Path, field: str, words: str) -> str:
    """The one line of ``err`` after "error: ": it names ``path`` and ``field`` (a regular
    expression) and says ``words``."""
    line = err.strip()
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert re.match(rf"handeye-jax: error: {re.escape(str(path))}: {field}: ", line), line
    assert words in line, line
    return line.split("error: ", 1)[1]


@pytest.mark.parametrize("name", FORGERIES)
def test_a_forged_result_is_refused_by_predict_and_export_alike(folder, capsys, name):
    """Each forgery, its digest recomputed: ``predict`` (NumPy alone, JAX not importable) and
    ``export`` refuse it with the same line naming the file and the field."""
    edit, field, words = FORGERIES[name]
    path = _edited(folder, name.replace(" ", "_"), edit)
    code = "from handeye_jax.cli import main\nsys.exit(main(sys.argv[1:]))"
    p = run_without_jax(code, "predict", str(path), str(folder / "pts.csv"))
    assert p.returncode == 2 and p.stdout == "", (p.stdout, p.stderr)
    said = _one_line(p.stderr, path, field, words)
    capsys.readouterr()
    assert main(["export", str(path), "--format", "json"]) == 2
    assert _one_line(capsys.readouterr().err, path, field, words) == said
    with pytest.raises(InputError) as e:
        Predictor.from_result(path)
    assert str(e.value) == said


def test_a_perfect_forgery_is_refused_by_the_rigs_reach(folder, capsys):
    """fx = 400 and Sx1 = 999 made consistent everywhere by the toolkit's own writer: its own
    landmarks' hand commands lie tens of metres from where the hand touched them."""
    path = _perfect_forgery(folder, 400.0, 999.0)
    said = []
    for argv in (["predict", str(path), str(folder / "pts.csv")],
                 ["export", str(path), "--format", "json"]):  # fmt: skip
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err
        said.append(_one_line(err, path, r"stage2\.residuals_mm\[\d\]", "outside the rig's reach"))
        assert "the hand positions the calibration recorded ± 500 mm" in err
    assert said[0] == said[1]


def test_a_result_as_written_still_predicts_without_jax_in_a_fraction_of_a_second(folder):
    code = """
        import time
        from handeye_jax.cli import main
        t = time.perf_counter()
        code = main(sys.argv[1:])
        print(json.dumps({"code": code, "s": time.perf_counter() - t}), file=sys.stderr)
        """
    p = run_without_jax(code, "predict", str(folder / "good.json"), str(folder / "pts.csv"))
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stderr.splitlines()[-1])["code"] == 0
    assert len(p.stdout.splitlines()) == 3


def test_predict_refuses_a_hand_command_beyond_the_rigs_reach(folder, tmp_path, capsys):
    """A depth in the wrong unit sends the hand 6 m away: refused naming the point's line,
    nothing written. Points seen from another capture pose widen the reach by that pose."""
    far = tmp_path / "far.csv"
    far.write_text("u,v,depth,hand_angle\n338,244,169.2,90\n119,105,16820,0\n")
    out = tmp_path / "out.csv"
    assert main(["predict", str(folder / "good.json"), str(far), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"handeye-jax: error: {far}: line 3: its hand command (")
    assert "mm outside the rig's reach (x " in err and err.count("\n") == 1
    assert not out.exists()
    moved = tmp_path / "moved.csv"  # the robot took this picture 2 m further along x
    moved.write_text("u,v,depth,hand_angle,capture_x,capture_y,capture_z\n"
                     "338,244,169.2,90,2320,-70,290\n")  # fmt: skip
    assert main(["predict", str(folder / "good.json"), str(moved)]) == 0
    assert float(capsys.readouterr().out.splitlines()[1].split(",")[-2]) > 2000


@settings(max_examples=60, deadline=None)
@given(data=st.data(), value=JSON_VALUES)
def test_any_changed_field_is_checked_without_jax_or_refused_in_one_line(folder, data, value):
    """Any field of a result changed (its digest recomputed, so predict takes it without the
    full reader): the NumPy checks load it usably or refuse it in one line, no other error."""
    good = json.loads((folder / "good.json").read_text())
    where = data.draw(st.sampled_from([p for p in _paths(good) if p and p[0] != DIGEST_KEY]))
    doc = json.loads(json.dumps(good))
    _set(doc, where, value)
    path = folder / "changed.json"
    try:
        path.write_text(_with_digest(doc))
    except ValueError:  # NaN or infinity: no digest (the writer writes neither)
        path.write_text(json.dumps(doc))
    for read in (Predictor.from_result, stored_result):
        try:
            got = read(path)
        except InputError as e:
            assert len(str(e).splitlines()) == 1 and str(e).startswith(f"{path}: "), str(e)
            continue
        if got is not None:
            p = Predictor.from_frames(*got) if read is stored_result else got
            assert np.isfinite(p.hand_command([[338.0, 244]], [169.2], [90.0])).all()


def test_predictor_reach_is_the_recorded_hand_positions_with_a_margin(folder):
    p = Predictor.from_result(folder / "good.json")
    ds = load_dataset(PAPER)
    xy = np.vstack([ds.hand_xy_mm, ds.captures[0].hand_position_mm[:2]])
    np.testing.assert_array_equal(p.reach.lo_mm[:2], xy.min(axis=0))
    np.testing.assert_array_equal(p.reach.hi_mm[:2], xy.max(axis=0))
    inside = p.reach.hi_mm[:2] + p.reach.margin_mm - 1.0
    assert p.reach.excess_mm([inside, inside + [2.0, 0.0]]).tolist() == [0.0, 1.0]


@settings(max_examples=30, deadline=None)
@given(case=cases())
def test_the_numpy_frames_are_the_models_frames(case):
    """The NumPy twins the checks use give every registered model's frames within 1e-12."""
    from handeye_jax.robot._npframes import MODELS, mount_pose_pen

    ours = {n: c for n, c in model_registry().items() if c.__module__.startswith("handeye_jax.")}
    assert set(MODELS) == set(ours)  # the toolkit's models (tests define others)
    for name, cls in ours.items():
        assert MODELS[name][0] == cls.param_names
    f = case.frames()
    R_hc, t_hc, R_bt, t_bt, t_hp = mount_pose_pen(case.model, case.params)
    for got, want in ((R_hc, f.R_hand_camera), (t_hc, f.t_hand_camera_mm),
                      (R_bt, f.R_base_tablet), (t_bt, f.t_base_tablet_mm),
                      (t_hp, f.t_hand_pen_mm)):  # fmt: skip
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


# -- a prior edited, or of another rig -------------------------------------------------------


@pytest.fixture(scope="module")
def new(folder):
    """New data of the same rig: the paper's dataset text, to be edited."""
    return PAPER.read_text()


def _calibrate_from(prior: Path, dataset: Path, *more: str) -> list[str]:
    return ["calibrate", str(dataset), "--prior", str(prior), "--refit", "pen", "--no-diagnostics",
            *FAST, *more]  # fmt: skip


@pytest.mark.parametrize("name", ["parameters only", "parameters and frames"])
def test_an_edited_prior_is_refused_before_the_fit(folder, tmp_path, capsys, name):
    """xt + 10 mm in the prior's parameters (and its frames, its digest recomputed): the
    recalibration refuses it, naming the prior's file and field, before any work."""
    edits = [_put("stage1", "params", "xt", lambda v: v + 10.0)]
    if name == "parameters and frames":
        edits.append(_put("frames", "T_base_tablet", "t", "mm", 0, lambda v: v + 10.0))
    prior = _edited(folder, f"prior_{name.replace(' ', '_')}", _both(*edits))
    out = tmp_path / "new.json"
    capsys.readouterr()
    assert main([*_calibrate_from(prior, PAPER), "--out", str(out)]) == 2
    field = (
        "frames"
        if name == "parameters only"
        else (r"stage1\.residuals_mm\[\d\]\.image_vs_tablet_xy_mm")
    )
    _one_line(capsys.readouterr().err, prior, field, "the file was edited after the fit")
    assert not out.exists()


FOREIGN = [
    ("\nfx = 617.7", "\nfx = 630.0", "camera.fx", "is 630 px; the prior good.json was fitted with "
     "617.7 px"),
    ("\ncy = 242.3", "\ncy = 250.0", "camera.cy", "is 250 px; the prior good.json was fitted with "
     "242.3 px"),
    ("\nppi = 267.0", "\nppi = 264.0", "tablet.ppi", "is 264; the prior good.json was fitted "
     "with 267"),
    ("\nsign = -1", "\nsign = 1", "hand_angle.sign", "is 1; the prior good.json was fitted "
     "with -1"),
    ("\nzero = 90.0", "\nzero = 0.0", "hand_angle.zero", "is 0 deg; the prior good.json was fitted "
     "with 90 deg"),
]  # fmt: skip


@pytest.mark.parametrize("old,changed,field,words", FOREIGN, ids=[f[2] for f in FOREIGN])
def test_a_prior_of_another_rig_is_refused_naming_the_field_and_both_values(
    folder, new, tmp_path, capsys, old, changed, field, words
):
    assert old in new
    dataset = tmp_path / "new.toml"
    dataset.write_text(new.replace(old, changed, 1))
    capsys.readouterr()
    assert main(_calibrate_from(folder / "good.json", dataset)) == 2
    line = _one_line(capsys.readouterr().err, dataset, field, words)
    assert "--accept-rig-change" in line


def test_a_deliberate_rig_change_is_accepted_and_said(folder, new, tmp_path, capsys):
    """A re-calibrated camera: --accept-rig-change fits, the summary and the result say so."""
    dataset = tmp_path / "recalibrated.toml"
    dataset.write_text(new.replace("\nfx = 617.7", "\nfx = 630.0", 1))
    out = tmp_path / "new.json"
    capsys.readouterr()
    assert main([*_calibrate_from(folder / "good.json", dataset), "--accept-rig-change",
                 "--out", str(out)]) == 0  # fmt: skip
    summary = capsys.readouterr().out
    assert ("the rig changed since the prior, accepted (--accept-rig-change): camera.fx "
            "617.7 px → 630 px") in summary  # fmt: skip
    doc = json.loads(out.read_text())
    assert doc["recalibration"]["rig_changes"] == [
        {"field": "camera.fx", "previous": 617.7, "new": 630.0, "unit": "px"}
    ]
    assert load_result(out).rig.fx_px == 630.0  # the new rig's, and the file checks out
    capsys.readouterr()
    assert main(["calibrate", str(PAPER), "--accept-rig-change", *FAST]) == 2
    assert "--accept-rig-change: needs --prior" in capsys.readouterr().err


# -- a FIFO given as a result; a negative seed --------------------------------------------------


def _returns_within(seconds: float, fifo: Path, call):
    """``call()``'s outcome, or a failure if it is still blocked after ``seconds`` (then the
    FIFO is opened for writing, which releases it)."""
    outcome = {}

    def run():
        try:
            outcome["value"] = call()
        except BaseException as e:  # noqa: BLE001 - handed to the test
            outcome["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    if t.is_alive():
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)  # a reader waits: this succeeds
        os.close(fd)
        t.join(10)
        pytest.fail(f"still blocked after {seconds} s on a FIFO")
    return outcome


def test_a_fifo_given_as_a_result_is_refused_at_once(folder, tmp_path, capsys):
    fifo = tmp_path / "result.json"
    os.mkfifo(fifo)
    got = _returns_within(10, fifo, lambda: Predictor.from_result(fifo))
    assert isinstance(got.get("error"), InputError), got
    assert str(got["error"]) == f"{fifo}: cannot read file: not a regular file (a FIFO)"
    capsys.readouterr()
    got = _returns_within(10, fifo, lambda: main(["predict", str(fifo), str(folder / "pts.csv")]))
    assert got.get("value") == 2, got
    err = capsys.readouterr().err
    assert err == f"handeye-jax: error: {fifo}: cannot read file: not a regular file (a FIFO)\n"


def test_a_negative_seed_is_refused_before_the_fit(capsys):
    with pytest.raises(SystemExit) as e:  # argparse's exit, at parse time
        main(["calibrate", str(PAPER), "--seed=-1", *FAST])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err == ("handeye-jax calibrate: error: argument --seed: must be 0 to 2^63 - 1: "
                   "numpy's generators take no other seed (got -1) (see --help)\n")  # fmt: skip
    with pytest.raises(ValueError, match=r"seed must be 0 to 2\^63 - 1"):
        calibrate(load_dataset(PAPER), replace(FAST_SETTINGS, seed=-1))
