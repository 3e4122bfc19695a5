"""Reading a result file: every field used is checked; bad input is one line naming the field."""

import dataclasses
import json
import shutil

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from handeye_jax import (
    CalibrationResult,
    FitWarning,
    InputError,
    PolishSummary,
    Settings,
    StageResult,
    load_result,
    save_result,
)
from handeye_jax._core import REPORT_FIGURES as FIGURES
from handeye_jax._core import REPORT_FORMATS as FORMATS
from handeye_jax.calibration._settings import SETTINGS_SCHEMA
from handeye_jax.cli import main
from handeye_jax.report._figures import fig_convergence

POINTS = "u,v,depth,hand_angle\n338,244,169.2,90\n119,105,168.2,0\n"


@pytest.fixture(scope="module")
def folder(tmp_path_factory, paper_result_file):
    """A result the toolkit wrote (``good.json``) and a points CSV (``pts.csv``)."""
    folder = tmp_path_factory.mktemp("result_input")
    shutil.copy(paper_result_file, folder / "good.json")
    (folder / "pts.csv").write_text(POINTS)
    return folder


@pytest.fixture(scope="module")
def good_doc(folder):
    return json.loads((folder / "good.json").read_text())


def _set(doc, path, value):
    """Set (or with ``...`` delete) the value at ``path``, a tuple of keys and indices."""
    *head, last = path
    for k in head:
        doc = doc[k]
    if value is ...:
        del doc[last]
    else:
        doc[last] = value


def _one_line_error(capsys, argv, path, field):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1, err
    assert str(path) in err and "Traceback" not in err
    assert f": {field}: " in err if field else f"{path}: " in err, err
    return err


# -- the audit's defects, through the command line ----------------------------------------

R, D, DATA = ("stage1", "residuals_mm"), ("diagnostics", "stage1"), ("data",)
BAD_FIELDS = [
    # 1. centre_index and warnings
    (("centre_index",), "abc", "centre_index", "must be an integer"),
    (("centre_index",), None, "centre_index", "got null"),
    (("centre_index",), True, "centre_index", "must be an integer"),
    (("centre_index",), 99, "centre_index", "must be 0 to 8"),
    (("centre_index",), -1, "centre_index", "must be 0 to 8"),
    (("centre_index",), ..., "centre_index", "missing"),
    (("warnings",), 5, "warnings", "array of strings"),
    (("warnings",), ["ok", 3], "warnings[1]", "must be a string"),
    # 2. what the report and the evaluation read
    ((*R, 0), {"m": 0}, "stage1.residuals_mm[0].image_vs_tablet_xy_mm", "missing"),
    ((*R, 0, "image_vs_tablet_mm"), "x", "stage1.residuals_mm[0].image_vs_tablet_mm", "number"),
    ((*R, 3, "hand_mm"), -0.5, "stage1.residuals_mm[3].hand_mm", ">= 0"),
    ((*R, 2, "m"), 7, "stage1.residuals_mm[2].m", "landmark order"),
    (R, 5, "stage1.residuals_mm", "must be an array"),
    (("stage2", "residuals_mm", 0, "hand_xy_mm"), [1.0], "stage2.residuals_mm[0].hand_xy_mm", ""),
    (D, [], "diagnostics.stage1", "must be an object"),
    (("diagnostics",), [1, 2], "diagnostics", "must be an object"),
    (("stage1", "convergence"), [], "stage1.convergence", "must be an object"),
    (("stage2", "convergence", "best_F", 0), "x", "stage2.convergence.best_F[0]", "number"),
    (
        ("stage1", "convergence", "median_generation"),
        [1, 2, 3],
        "stage1.convergence.median_generation",
        "one generation per median_F",
    ),
    (
        ("stage1", "convergence", "median_generation", 0),
        0,
        "stage1.convergence.median_generation[0]",
        "at least 1",
    ),
    (("stage1", "de"), "x", "stage1.de", "must be an object"),
    (("stage1", "de", "generations"), "many", "stage1.de.generations", "integer"),
    (("stage2", "polish", "steps"), -1, "stage2.polish.steps", "at least 0"),
    (("stage2", "polish", "accepted"), "yes", "stage2.polish.accepted", "true or false"),
    (("stage1", "F"), -1.0, "stage1.F", ">= 0"),
    ((*D, "loo", "in_sample_F"), ..., "diagnostics.stage1.loo.in_sample_F", "missing"),
    ((*D, "loo", "held_out_mm"), [{"m": 0}], "diagnostics.stage1.loo.held_out_mm", "list of 9"),
    (
        (*D, "loo", "held_out_mm", 4, "hand_mm"),
        None,
        "diagnostics.stage1.loo.held_out_mm[4].hand_mm",
        "must be a number",
    ),
    (("settings",), [1, 2], "settings", "must be an object"),
    (("settings", "population"), 2, "settings.population", "must be 4 to 100000"),
    # sizes evaluate once allocated from (issue 16, section 3): 80 GB for population 10^9
    (("settings", "population"), 10**9, "settings.population", "must be 4 to 100000"),
    (("settings", "generations"), 10**9, "settings.generations", "must be 1 to 100000"),
    ((*R,), [{"m": 0}] * 10_001, "stage1.residuals_mm", "10,001 entries; at most 10,000"),
    ((*DATA, "landmarks"), [{}] * 10_001, "data.landmarks", "10,001 landmarks; at most 10,000"),
    (("settings", "loss"), "l3", "settings.loss", "unknown loss"),
    (("settings", "seed"), 2**64, "settings.seed", "must be"),
    (("dataset",), 7, "dataset", "must be a string"),
    (("model",), ["htm"], "model", "unknown model"),
    # 3. the data, read as a dataset file is
    ((*DATA, "landmarks", 0, "depth"), -1.0, "data.landmarks[0].depth", "must be > 0"),
    ((*DATA, "landmarks", 5, "depth"), 0, "data.landmarks[5].depth", "must be > 0"),
    ((*DATA, "landmarks", 1, "depth"), 2e6, "data.landmarks[1].depth", "at most"),
    ((*DATA, "landmarks", 2, "hand_xy", 1), 1e9, "data.landmarks[2].hand_xy[1]", "at most"),
    ((*DATA, "tablet", "ppi"), 1e308, "data.tablet.ppi", "at most"),
    ((*DATA, "tablet", "ppi"), 0.0, "data.tablet.ppi", "must be > 0"),
    ((*DATA, "tablet", "ppi"), 1.0, "data.tablet", "a screen's pixel is 0.01 to 3 mm"),
    ((*DATA, "tablet", "ppi"), 1e5, "data.tablet", "a screen's pixel is 0.01 to 3 mm"),
    # 4. stage-2 scales
    (("stage2", "params", "Sx1"), 0.0, "stage2.params.Sx1", "must be > 0"),
    (("stage2", "params", "Sy2"), -1.0, "stage2.params.Sy2", "must be > 0"),
    # others: the rig and the fit
    (("rig", "camera_px", "fx"), 0.5, "rig.camera_px.fx", "at least 1 px"),
    (("stage1", "params", "xt"), 1e30, "stage1.params.xt", "at most"),
    # each σ's degrees of freedom: a count > 0 (or null: no estimated scale)
    ((*D, "std_dof", "xt"), -1.0, "diagnostics.stage1.std_dof.xt", "must be > 0"),
    ((*D, "std_dof", "xt"), "many", "diagnostics.stage1.std_dof.xt", "number"),
    # a class's own check (found by the explore profile: it was a traceback)
    (("stage1", "noise", "noise", "image_sigma_px"), -1.0, "stage1.noise.noise",
     "image_sigma_px must be finite and >= 0"),
]


@pytest.mark.parametrize("path,value,field,says", BAD_FIELDS, ids=[c[2] for c in BAD_FIELDS])
def test_a_bad_field_is_one_line_naming_it(folder, good_doc, tmp_path, capsys, path, value,
                                           field, says):  # fmt: skip
    doc = json.loads(json.dumps(good_doc))
    _set(doc, path, value)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    out = tmp_path / "out.csv"
    argv = ["predict", str(bad), str(folder / "pts.csv"), "--out", str(out)]
    assert says in _one_line_error(capsys, argv, bad, field)
    figs = tmp_path / "figs"
    assert says in _one_line_error(capsys, ["report", str(bad), "--out", str(figs)], bad, field)
    assert not out.exists() and not figs.exists()


BAD_TEXTS = [
    # 5. a key twice, even with a valid value
    ('"fx": 617.7', '"fx": 617.7, "fx": 300.0', "rig.camera_px.fx", "duplicate key"),
    ('"Sx1": ', '"Sx1": 1.0, "Sx1": ', "stage2.params.Sx1", "duplicate key"),
    ('"format": ', '"warnings": [], "format": ', "warnings", "duplicate key"),
    # 6. integers beyond float64 and beyond Python's digits
    ('"fx": 617.7', '"fx": 1' + "0" * 400, "rig.camera_px.fx", "must be finite"),
    ('"fx": 617.7', '"fx": 1' + "0" * 5000, "", "an integer of 5001 digits"),
    ('"fx": 617.7', '"fx": ' + "[" * 100_000, "", "nested too deeply"),
]


@pytest.mark.parametrize("old,new,field,says", BAD_TEXTS, ids=[c[3] for c in BAD_TEXTS])
def test_bad_json_text_is_one_line(folder, tmp_path, capsys, old, new, field, says):
    text = (folder / "good.json").read_text()
    assert old in text
    bad = tmp_path / "bad.json"
    bad.write_text(text.replace(old, new, 1))
    argv = ["predict", str(bad), str(folder / "pts.csv")]
    assert says in _one_line_error(capsys, argv, bad, field)


# -- what the toolkit writes still loads ------------------------------------------------


def test_a_written_result_loads_predicts_and_reports(folder, tmp_path, capsys):
    good = folder / "good.json"
    result = load_result(good)
    out = tmp_path / "out.csv"
    assert main(["predict", str(good), str(folder / "pts.csv"), "--out", str(out)]) == 0
    got = np.loadtxt(out, delimiter=",", skiprows=1)[:, 4:]
    want = result.predict(np.array([[338.0, 244], [119, 105]]), np.array([169.2, 168.2]),
                          np.array([90.0, 0]))  # fmt: skip
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert main(["report", str(good), "--out", str(tmp_path / "figs")]) == 0
    assert sorted(p.name for p in (tmp_path / "figs").iterdir()) == sorted(
        f"{f}.{e}" for f in FIGURES for e in FORMATS
    )
    # What the API can write: no polish, no diagnostics, and the tablet tests' bare result.
    unpolished = dataclasses.replace(
        result.stage1, polish=PolishSummary(ran=False, accepted=False, F_before_mm=2.0)
    )
    bare = StageResult(F=1.0, f1=0.5, f2=0.5, params=result.stage2.params)
    for variant in (
        dataclasses.replace(result, stage1=unpolished, diagnostics=None),
        dataclasses.replace(result, data=None, diagnostics=None, stage2=bare),
        CalibrationResult(
            model=result.model, correction=result.correction, rig=result.rig,
            centres_mm=[[0.0, 0.0], [0.0, 0.0]], centre_index=4, stage1=result.stage1,
            stage2=bare, settings=Settings(seed=1), dataset_name="d", warnings=[FitWarning("w")],
        ),
    ):  # fmt: skip
        save_result(variant, tmp_path / "v.json")
        again = load_result(tmp_path / "v.json")
        assert _same(again, variant)


def _same(a: CalibrationResult, b: CalibrationResult) -> bool:
    """Equal results: every field, the models and correction by their parameters."""
    for f in dataclasses.fields(CalibrationResult):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name in ("model", "correction"):
            if type(x) is not type(y) or x.to_dict() != y.to_dict():
                return False
        elif f.name == "rig":
            if not all(np.array_equal(np.asarray(u), np.asarray(v)) for u, v in
                       zip(jax.tree.leaves(x), jax.tree.leaves(y), strict=True)):  # fmt: skip
                return False
        elif f.name == "centres_mm":
            if not np.array_equal(x, y):
                return False
        elif f.name != "fits" and x != y:
            return False
    return True


def test_an_older_result_with_observations_instead_of_data_loads(good_doc, tmp_path, capsys):
    """Results before the data section recorded the landmark arrays as ``observations``."""
    doc = json.loads(json.dumps(good_doc))
    data = doc.pop("data")
    mm = 25.4 / data["tablet"]["ppi"] * data["tablet"]["scale"]
    marks = data["landmarks"]
    doc["observations"] = {
        "tablet_px": [m["tablet_px"] for m in marks], "image_px": [m["image_px"] for m in marks],
        "depth_mm": [m["depth"] for m in marks], "hand_xy_mm": [m["hand_xy"] for m in marks],
        "hand_angle_deg": [m["hand_angle"] for m in marks],
        "touch_error_px": [m["touch_error_px"] for m in marks], "mm_per_tablet_px": mm,
    }  # fmt: skip
    old = tmp_path / "old.json"
    old.write_text(json.dumps(doc))
    r = load_result(old)
    assert r.data.mm_per_tablet_px == pytest.approx(mm, rel=1e-15)
    assert r.data.image_px.tolist() == doc["observations"]["image_px"]
    doc["observations"]["depth_mm"][3] = -2.0
    old.write_text(json.dumps(doc))
    assert "must be > 0" in _one_line_error(capsys, ["report", str(old)], old,
                                            "observations.depth_mm[3]")  # fmt: skip


def test_first_results_load_and_draw(good_doc, tmp_path):
    """The first results recorded the median F every generation and LM's pinned parameters."""
    doc = json.loads(json.dumps(good_doc))
    for s in ("stage1", "stage2"):
        c = doc[s]["convergence"]
        c["median_F"] = c["best_F"][:]
        del c["median_generation"]
        doc[s]["polish"]["pinned"] = ["xc"]
    p = tmp_path / "first.json"
    p.write_text(json.dumps(doc))
    r = load_result(p)
    generations = len(doc["stage1"]["convergence"]["best_F"])
    assert r.stage1.convergence.median_generation == tuple(range(1, generations + 1))
    fig_convergence(r)


def test_settings_checks_cover_the_settings():
    assert set(SETTINGS_SCHEMA) == {f.name for f in dataclasses.fields(Settings)}


# -- properties ------------------------------------------------------------------------


def _paths(x, path=()):
    yield path
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _paths(v, (*path, k))
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _paths(v, (*path, i))


JSON_VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**400), 10**400), st.floats(), st.text(max_size=4),
    st.lists(st.one_of(st.integers(-3, 3), st.floats(-1e7, 1e7)), max_size=3),
    st.dictionaries(st.sampled_from(["m", "F", "x"]), st.integers(-2, 2), max_size=2),
)  # fmt: skip


@settings(max_examples=60, deadline=None)
@given(data=st.data(), value=JSON_VALUES)
def test_any_changed_field_loads_usably_or_fails_in_one_line(folder, good_doc, data, value):
    path = data.draw(st.sampled_from([p for p in _paths(good_doc) if p]))
    doc = json.loads(json.dumps(good_doc))
    _set(doc, path, value)
    bad = folder / "changed.json"
    bad.write_text(json.dumps(doc))
    try:
        r = load_result(bad)
    except InputError as e:
        assert len(str(e).splitlines()) == 1 and str(e).startswith(f"{bad}: ")
        return
    xy = r.predict(np.array([[338.0, 244]]), np.array([169.2]), np.array([90.0]))
    assert np.isfinite(xy).all()


def _dumps_repeating(x, target, path=()):
    """JSON text of ``x`` in which the object at ``target`` has its first key twice."""
    if isinstance(x, dict):
        items = [(k, _dumps_repeating(v, target, (*path, k))) for k, v in x.items()]
        if path == target:
            items.insert(1, (items[0][0], "null"))
        return "{" + ", ".join(f"{json.dumps(k)}: {v}" for k, v in items) + "}"
    if isinstance(x, list):
        return (
            "[" + ", ".join(_dumps_repeating(v, target, (*path, i)) for i, v in enumerate(x)) + "]"
        )
    return json.dumps(x)


def _field(path):
    return "".join(f"[{k}]" if isinstance(k, int) else f".{k}" for k in path).lstrip(".")


@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_a_repeated_key_is_named_with_its_path(folder, good_doc, data):
    objects = [
        p for p in _paths(good_doc) if _at(good_doc, p) and isinstance(_at(good_doc, p), dict)
    ]
    target = data.draw(st.sampled_from(objects))
    bad = folder / "repeated.json"
    bad.write_text(_dumps_repeating(good_doc, target))
    with pytest.raises(InputError) as e:
        load_result(bad)
    first = next(iter(_at(good_doc, target)))
    assert e.value.field == _field((*target, first)) and "duplicate key" in str(e.value)


def _at(doc, path):
    for k in path:
        doc = doc[k]
    return doc
