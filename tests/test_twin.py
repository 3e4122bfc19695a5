"""The synthetic twin: its truth, its determinism, its evaluation, and the commands end to end."""

import functools
import importlib.util
import json
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from handeye_jax import (
    PRESETS,
    Dataset,
    Heldout,
    HTMModel,
    InputError,
    Scene,
    Settings,
    Stage1Objective,
    draw_truth,
    evaluate,
    load_dataset,
    load_heldout,
    load_result,
    load_truth,
    save_dataset,
    simulate,
    synthesize_dataset,
    write_twin,
)
from handeye_jax.cli import main
from handeye_jax.twin._evaluate import landing_tablet_px, landmarks_fitted
from handeye_jax.twin._truth import RANGES

ROOT = Path(__file__).resolve().parents[1]
FAST = ["--population", "200", "--generations", "400", "--no-progress"]


@pytest.mark.parametrize("seed", [0, 7, 123])
def test_truth_json_round_trips_and_stays_in_range(tmp_path, seed):
    truth = draw_truth(seed)
    path = tmp_path / "truth.json"
    path.write_text(truth.to_json())
    assert load_truth(path) == truth
    for name, value in truth.model.items():
        lo, hi = RANGES[name]
        assert lo <= value <= hi and HTMModel.default_ranges[name][0] < value
    assert draw_truth(seed) == truth and draw_truth(seed + 1) != truth


@pytest.mark.parametrize(
    "change,field",
    [
        (lambda d: d.pop("ppi"), "ppi"),
        (lambda d: d["model"].update(xc="x"), "model.xc"),
        (lambda d: d.update(hand_angle_sign=0), "hand_angle_sign"),
        (lambda d: d.update(dot_px=-1), "dot_px"),
        (lambda d: d["capture_position_mm"].__setitem__(0, 1000.0), "not in the picture"),
        (lambda d: d.update(format="other"), "format"),
        (lambda d: d.update(ppi=1e-320), "ppi: must be at least 1"),
        (lambda d: d.update(scale=1e308), "scale: must be at most 100"),
        (lambda d: d["camera_px"].update(fx=1e-300), "camera_px.fx: must be at least 1 px"),
        (lambda d: d.update(camera_z_mm=10**400), "camera_z_mm: must be finite"),
        # sizes the renderer would allocate from (issue 16, section 3)
        (lambda d: d.update(image_size_px=[100_000, 100_000]), "image_size_px: 100000 x 100000"),
        (lambda d: d.update(lens_blur_px=1e3), "lens_blur_px: must be at most 20"),
        (lambda d: d.update(dot_px=1e5), "dot_px: must be at most 50"),
        (lambda d: d.update(landmarks_tablet_px=[[1.0, 1.0]] * 10_001), "landmarks_tablet_px"),
        (lambda d: d.update(ppi=1.0, scale=100.0), "scale: one tablet px is 25.4 / ppi"),
    ],
)
def test_bad_truth_json_names_the_field(tmp_path, change, field):
    doc = draw_truth(1).to_dict()
    change(doc)
    path = tmp_path / "truth.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=field) as e:
        load_truth(path)
    assert str(path) in str(e.value)


def _f1st(ds: Dataset, truth) -> float:
    return float(Stage1Objective(HTMModel, ds.observations())(truth.htm().to_vector()))


def test_exact_noise_free_twin_is_fitted_exactly_by_its_truth():
    truth = draw_truth(4)
    twin = simulate(truth, PRESETS["none"], 4, exact=True, n_heldout=5)
    assert _f1st(twin.dataset, truth) < 1e-9
    # Detected instead of exact: only the centroid and 1-mm depth errors remain.
    detected = simulate(truth, PRESETS["none"], 4, n_heldout=5)
    assert 1e-6 < _f1st(detected.dataset, truth) < 0.2


def test_same_seed_same_bits_and_noise_where_the_preset_says():
    truth = draw_truth(6)
    a = simulate(truth, PRESETS["paper"], 6, n_heldout=4)
    b = simulate(truth, PRESETS["paper"], 6, n_heldout=4)
    assert a.capture.tobytes() == b.capture.tobytes() and a.depth.tobytes() == b.depth.tobytes()
    assert a.dataset == b.dataset
    c = simulate(truth, PRESETS["paper"], 7, n_heldout=4)
    assert c.capture.tobytes() != a.capture.tobytes()
    ds = a.dataset
    assert np.array_equal(ds.hand_xy_mm, np.round(ds.hand_xy_mm))  # whole mm, as in Table 2
    assert np.array_equal(ds.touch_error_px, np.round(ds.touch_error_px))
    assert np.any(ds.touch_error_px != 0)
    assert a.depth.dtype == np.uint16 and 0 < np.mean(a.depth == 0) < 0.05


@settings(max_examples=25, deadline=None)
@given(
    x=st.floats(400, 1040), y=st.floats(150, 550), angle=st.floats(0, 180),
    touch=st.tuples(st.floats(-5, 5), st.floats(-5, 5)),
)  # fmt: skip
def test_pen_lands_where_the_true_chain_says(x, y, angle, touch):
    truth = _truth()
    target = np.array([[x, y]])
    ds = synthesize_dataset(
        truth.htm(), truth.rig(), target, np.array([angle]),
        scene=Scene(ppi=truth.ppi, scale=truth.scale), touch_error_px=np.array([touch]),
    )  # fmt: skip
    landed = landing_tablet_px(truth, ds.hand_xy_mm, np.array([angle]))
    np.testing.assert_allclose(landed - target, [touch], atol=1e-9)


@functools.cache
def _truth():
    """A twin truth, drawn at first use (collection, which every test process does, stays
    free of JAX's computations)."""
    return draw_truth(8)


class _Perfect:
    """A stand-in result that commands with the true model: it must land exactly."""

    def __init__(self, truth):
        self.truth = truth

    def predict(self, image_px, depth_mm, hand_angle_deg, stage=2):
        from handeye_jax import Targets, hand_command

        t = self.truth
        targets = Targets(jnp.asarray(image_px), jnp.asarray(depth_mm), jnp.asarray(hand_angle_deg))
        return np.asarray(hand_command(t.htm(), t.rig(), targets))


def test_evaluate_gives_zero_for_the_truth_on_exact_observations():
    truth = _truth()
    twin = simulate(truth, PRESETS["none"], 1, exact=True, n_heldout=6)
    # Exact held-out observations: the true image points and depths.
    image_px, depth_mm = truth.project(twin.heldout_tablet_px)
    held = Heldout(image_px, depth_mm, twin.heldout_hand_angle_deg, twin.heldout_tablet_px)
    rows = evaluate(_Perfect(truth), truth, held)
    assert [r.label for r in rows] == ["stage 1", "stage 2", "oracle"]
    for r in rows:
        assert r.max_mm < 1e-9
    # A model off by 1 mm in the pen offset misses by about that much.
    wrong = HTMModel.from_dict(dict(truth.model, xp=truth.model["xp"] + 1.0))

    class _Off(_Perfect):
        def predict(self, image_px, depth_mm, hand_angle_deg, stage=2):
            from handeye_jax import Targets, hand_command

            targets = Targets(jnp.asarray(image_px), jnp.asarray(depth_mm),
                              jnp.asarray(hand_angle_deg))  # fmt: skip
            return np.asarray(hand_command(wrong, truth.rig(), targets))

    off = evaluate(_Off(truth), truth, held)[0]
    assert 0.99 < off.mean_mm < 1.01 and abs(off.mean_px * off.mm_per_px - off.mean_mm) < 1e-12


def test_heldout_csv_errors(tmp_path):
    p = tmp_path / "heldout.csv"
    p.write_text("u,v,depth,hand_angle,tablet_x\n1,2,3,4,5\n")
    with pytest.raises(InputError, match="tablet_y"):
        load_heldout(p)
    p.write_text("u,v,depth,hand_angle,tablet_x,tablet_y\n1,2,3,4,5,x\n")
    with pytest.raises(InputError, match="tablet_y"):
        load_heldout(p)


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    """simulate -> detect -> calibrate through the command line: (twin folder, result file)."""
    folder = tmp_path_factory.mktemp("loop")
    twin = folder / "twin"
    assert main(["simulate", str(twin), "--seed", "2", "--preset", "paper"]) == 0
    names = {p.name for p in twin.iterdir()}
    assert names == {"dataset.toml", "capture.png", "depth.png", "truth.json", "heldout.csv"}
    ds = twin / "dataset.toml"
    assert main(["detect", str(twin / "capture.png"), str(twin / "depth.png"),
                 "--dataset", str(ds), "--out", str(folder / "detected.toml")]) == 0  # fmt: skip
    assert load_dataset(folder / "detected.toml") == load_dataset(ds)
    result = folder / "result.json"
    assert main(["calibrate", str(folder / "detected.toml"), "--out", str(result), *FAST]) == 0
    return twin, result


def test_simulate_detect_calibrate_evaluate_end_to_end(loop, capsys):
    twin, result = loop
    capsys.readouterr()
    assert main(["evaluate", str(result), str(twin)]) == 0
    out = capsys.readouterr().out
    rows = {
        line.split("|")[1].strip(): [float(v) for v in line.split("|")[2:6]]
        for line in out.splitlines()
        if line.startswith(("| stage", "| oracle"))
    }
    assert set(rows) == {"stage 1", "stage 2", "oracle", "oracle + stage 2"}
    # With Table 2's noise the oracle touches within a few tenths of a mm; a calibration
    # from nine landmarks is worse, but within a mm on average.
    assert rows["oracle"][0] < 0.3 and rows["stage 1"][0] < 1.0 and rows["stage 2"][0] < 1.0
    assert rows["oracle"][0] < rows["stage 1"][0]
    held = load_heldout(twin / "heldout.csv")
    assert held.image_px.shape == (20, 2)
    assert load_result(result).dataset_name.startswith("twin-seed2")


def _one_line(capsys, *needles) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("handeye-jax: error: "), err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


def test_evaluate_refuses_a_result_fitted_on_another_dataset(loop, tmp_path, capsys):
    truth = _truth()
    twin, result = loop
    other = tmp_path / "other"
    write_twin(simulate(truth, PRESETS["none"], 5, exact=True, n_heldout=2), other)
    assert main(["evaluate", str(result), str(other)]) == 2
    _one_line(capsys, f"{result}: dataset: fitted on dataset 'twin-seed2-paper', not on "
              f"'twin-seed5-none' ({other / 'dataset.toml'})")  # fmt: skip
    # The same name, one value changed: the data, not only the name, must be the result's.
    edited = tmp_path / "edited"
    edited.mkdir()
    for name in ("dataset.toml", "truth.json", "heldout.csv"):
        (edited / name).write_bytes((twin / name).read_bytes())
    ds = load_dataset(edited / "dataset.toml")
    touched = ds.touch_error_px.copy()
    touched[4, 0] += 1.0
    save_dataset(ds.replace(touch_error_px=touched), edited / "dataset.toml")
    assert main(["evaluate", str(result), str(edited)]) == 2
    _one_line(capsys, str(result), "whose touch_error_px differs from", str(edited))


def test_a_part_of_a_twin_calibrates_and_evaluates_on_the_whole_twin(loop, tmp_path, capsys):
    twin, _ = loop
    part = tmp_path / "part.json"
    assert main(["calibrate", str(twin / "dataset.toml"), "--landmarks", "8,0,4",
                 "--out", str(part), "--no-diagnostics", *FAST]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "fitting landmarks 8, 0, 4 of the 9 in dataset.toml (--landmarks)" in out
    fitted = load_result(part).data
    whole = load_dataset(twin / "dataset.toml")
    assert fitted == whole.landmark_subset([8, 0, 4])
    assert main(["evaluate", str(part), str(twin)]) == 0
    assert "| stage 2 |" in capsys.readouterr().out
    # A part whose landmarks are not the twin's is still refused.
    moved = fitted.replace(tablet_px=fitted.tablet_px + 1.0)
    assert landmarks_fitted(moved, whole) is None


def test_landmarks_beyond_the_dataset_are_refused_naming_it(loop, capsys):
    twin, _ = loop
    assert main(["calibrate", str(twin / "dataset.toml"), "--landmarks", "0,9", *FAST]) == 2
    _one_line(capsys, "dataset.toml: --landmarks: landmark 9: the dataset has 9 landmarks, "
              "m = 0 to 8")  # fmt: skip


@pytest.mark.parametrize(
    "value, needle",
    [("1,2,1", "landmark 1 given twice"), ("0,\uff13", "not a whole number: '\uff13'"),
     ("-1,2", "must be 0 to 9,999 (got -1)"), ("0,,4", "not a whole number: ''")],
)  # fmt: skip
def test_a_bad_landmarks_option_is_one_line(value, needle, capsys):
    with pytest.raises(SystemExit) as e:
        main(["calibrate", "any.toml", f"--landmarks={value}"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"error: argument --landmarks: {needle}" in err, err


class _Stop(Exception):
    pass


def test_evaluate_is_not_sized_by_the_results_settings(loop, tmp_path, monkeypatch):
    import handeye_jax.twin._evaluate as evaluate_module

    twin, result = loop
    doc = json.loads(result.read_text())
    doc["settings"].update(population=100_000, generations=100_000)  # the most a file may say
    big = tmp_path / "big.json"
    big.write_text(json.dumps(doc))
    seen = []

    def spy(dataset, model, settings):  # stops before the fit: only the budget is of interest
        seen.append(settings)
        raise _Stop

    monkeypatch.setattr(evaluate_module, "fit_correction", spy)
    with pytest.raises(_Stop):
        evaluate_module.evaluate_twin(big, twin)
    default = Settings()
    assert (seen[0].population, seen[0].generations) == (default.population, default.generations)
    assert seen[0].seed == doc["seed"] and seen[0].loss == doc["settings"]["loss"]
    with pytest.raises(_Stop):  # a smaller budget than the default is kept, as calibrated
        evaluate_module.evaluate_twin(result, twin)
    assert (seen[1].population, seen[1].generations) == (200, 400)


def _snapshot(folder: Path) -> dict:
    return {p: None if p.is_dir() else p.read_bytes() for p in sorted(folder.rglob("*"))}


def test_simulate_refuses_a_folder_that_is_not_empty_unless_forced(tmp_path, capsys):
    truth = _truth()
    folder = tmp_path / "twin"
    write_twin(simulate(truth, PRESETS["none"], 1, exact=True, n_heldout=2), folder)
    (folder / "result.json").write_text("{}")  # made from the old twin
    (folder / "result_report").mkdir()
    (folder / "result_report" / "convergence.png").write_bytes(b"png")
    (folder / "notes.txt").write_text("mine")
    before = _snapshot(folder)
    argv = ["simulate", str(folder), "--exact", "--preset", "none", "--heldout", "2"]
    assert main(argv) == 2
    _one_line(capsys, f"{folder}: not empty (holds capture.png, dataset.toml, depth.png, "
              "heldout.csv and 4 more)", "--force")  # fmt: skip
    assert _snapshot(folder) == before
    with pytest.raises(InputError, match="not empty"):
        write_twin(simulate(truth, PRESETS["none"], 2, exact=True, n_heldout=2), folder)
    assert _snapshot(folder) == before

    assert main([*argv, "--seed", "7", "--force"]) == 0
    out = capsys.readouterr().out
    removed = "removed what was made from the old twin: result.json, result_report/convergence.png"
    assert removed in out
    assert sorted(p.name for p in folder.iterdir()) == [
        "capture.png", "dataset.toml", "depth.png", "heldout.csv", "notes.txt", "truth.json"
    ]  # fmt: skip
    assert (folder / "notes.txt").read_text() == "mine"
    assert load_truth(folder / "truth.json") == draw_truth(7)
    assert load_dataset(folder / "dataset.toml").name == "twin-seed7-none"


@pytest.mark.parametrize(
    "option,value,says",
    [
        ("--seed", "-1", "must be 0 to 2^63 - 1"),
        ("--seed", "\uff11", "not a whole number"),  # a full-width 1
        ("--heldout", "10000000", "must be 1 to 10,000"),
        ("--dot-px", "1e300", "at most 50"),
    ],
)
def test_simulate_refuses_nonsense_options_by_name(tmp_path, capsys, option, value, says):
    with pytest.raises(SystemExit) as e:
        main(["simulate", str(tmp_path / "t"), option, value])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"argument {option}: " in err and says in err, err
    assert not (tmp_path / "t").exists()


def test_simulate_from_a_truth_file_and_exact(tmp_path, capsys):
    truth_path = tmp_path / "truth.json"
    truth_path.write_text(draw_truth(9).to_json())
    out = tmp_path / "exact"
    assert main(["simulate", str(out), "--truth", str(truth_path), "--exact", "--preset",
                 "none", "--heldout", "3"]) == 0  # fmt: skip
    assert load_truth(out / "truth.json") == load_truth(truth_path)
    twin = simulate(load_truth(truth_path), PRESETS["none"], 1, exact=True, n_heldout=3)
    np.testing.assert_allclose(load_dataset(out / "dataset.toml").image_px,
                               twin.landmarks_image_px, atol=1e-12)  # fmt: skip


def test_simulate_and_evaluate_input_errors(tmp_path, capsys):
    truth = _truth()
    bad = tmp_path / "truth.json"
    bad.write_text("{")
    assert main(["simulate", str(tmp_path / "o"), "--truth", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "truth.json" in err and "not valid JSON" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
    assert main(["simulate", str(tmp_path / "no" / "such" / "dir")]) == 2
    assert f"folder {str(tmp_path / 'no' / 'such')!r} does not exist" in capsys.readouterr().err
    (tmp_path / "afile").write_text("mine")
    assert main(["simulate", str(tmp_path / "afile")]) == 2
    assert "afile: cannot write: is a file, not a folder" in capsys.readouterr().err
    assert (tmp_path / "afile").read_text() == "mine"
    write_twin(simulate(truth, PRESETS["none"], 1, exact=True, n_heldout=2), tmp_path / "t")
    assert main(["evaluate", str(tmp_path / "missing.json"), str(tmp_path / "t")]) == 2
    assert "missing.json" in capsys.readouterr().err


def test_twin_study_runs_at_a_tiny_size(tmp_path, monkeypatch, capsys):
    # In this process, so it reuses the compiled DE of the end-to-end test (same budget).
    spec = importlib.util.spec_from_file_location(
        "twin_study", ROOT / "benchmarks" / "twin_study.py"
    )
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    results = tmp_path / "RESULTS.md"
    results.write_text("# Benchmark results\n\nkept\n\n## Later section\n\nalso kept\n")
    argv = ["twin_study.py", "--seeds", "3", "--population", "200", "--generations", "400",
            "--results", str(results)]  # fmt: skip
    monkeypatch.setattr(sys, "argv", argv)
    study.main()
    text = results.read_text()
    assert text.startswith("# Benchmark results\n\nkept\n") and "also kept" in text
    assert "## Synthetic twin: held-out touching error" in text and "| 3 |" in text
    assert "| mean |" in text and "stage 2 has the lower mean held-out error" in text
    study.main()  # a second run replaces its own section and nothing else
    again = results.read_text()
    assert again.count("## Synthetic twin") == 1 and again.count("also kept") == 1
