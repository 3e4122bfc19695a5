"""The NumPy predictor (issue 19, part 2): same numbers as the JAX path, no JAX on its path,
a capture pose per point, and one-line errors for bad files."""

from __future__ import annotations

import dataclasses
import json
import re
import runpy
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from frames_cases import (
    TOL_MM,
    Case,
    cases,
    jax_reference,
    jax_reference_of,
    points,
    run_without_jax,
)
from hypothesis import example, given, settings
from hypothesis import strategies as st

from handeye_jax import (
    Frames,
    InputError,
    Predictor,
    get_model,
    load_frames,
    load_result,
    save_result,
)
from handeye_jax.calibration._result_frames import UNDETERMINED
from handeye_jax.cli import main

ROOT = Path(__file__).resolve().parents[1]
FAST = settings(max_examples=25, deadline=None)


@pytest.fixture(scope="module")
def case() -> Case:
    return _fixed_case()


def _fixed_case() -> Case:
    """An HTM case near the paper's optimum (Table 7), with a non-trivial stage 2."""
    params = {"xc": -2.05, "yc": 34.09, "alpha_c": 0.49, "beta_c": 0.48, "gamma_c": -0.73,
              "xt": 193.33, "yt": 31.62, "alpha_t": 1.5, "beta_t": -11.9, "gamma_t": -1.2,
              "xp": -0.46, "yp": -22.27}  # fmt: skip
    affine = {"X1": -0.1, "Y1": 0.003, "theta1": 0.03, "Sx1": 0.998, "Sy1": 1.02,
              "X2": 0.06, "Y2": -0.11, "theta2": -0.02, "Sx2": 1.017, "Sy2": 0.988}  # fmt: skip
    return Case("htm", params, affine, (617.7, 617.7, 316.5, 242.3), (320.0, -70.0, 290.0),
                90.0, -1, ((326.5, -37.9), (325.9, -15.6)))  # fmt: skip


@pytest.fixture(scope="module")
def case_file(tmp_path_factory, case) -> Path:
    path = tmp_path_factory.mktemp("predictor") / "result.json"
    save_result(case.result(), path)
    return path


PAPER_POINTS = (
    np.array([[119.0, 105.0], [338.0, 244.0], [554.0, 381.0]]),
    np.array([168.2, 169.2, 168.9]),
    np.array([0.0, 90.0, 180.0]),
)


@FAST
@given(case=cases(), pts=points(), stage=st.sampled_from([1, 2]))
def test_predictor_matches_the_jax_path(case, pts, stage):
    """HTM and DH, both stages, parameters anywhere in the default ranges: within 1e-9 mm."""
    uv, depth, angle = pts
    got = Predictor.from_frames(case.frames()).hand_command(uv, depth, angle, stage=stage)
    want = jax_reference(case, uv, depth, angle, stage)
    assert got.shape == (len(uv), 2)
    np.testing.assert_allclose(got, want, rtol=0, atol=TOL_MM)


@settings(max_examples=10, deadline=None)
@given(case=cases(), pts=points(), stage=st.sampled_from([1, 2]))
def test_from_result_file_matches_the_loaded_result(tmp_path_factory, case, pts, stage):
    """Through the file: what ``calibrate --out`` writes, the predictor reads, and it agrees
    with the model, rig and correction ``load_result`` rebuilds from the same file (what
    ``CalibrationResult.predict`` evaluates, here jitted)."""
    path = tmp_path_factory.mktemp("r") / "r.json"
    save_result(case.result(), path)
    assert "frames" in json.loads(path.read_text())
    got = Predictor.from_result(path).hand_command(*pts, stage=stage)
    loaded = load_result(path)
    want = jax_reference_of(loaded.model, loaded.rig,
                            loaded.correction, loaded.centres_mm, *pts, stage)  # fmt: skip
    np.testing.assert_allclose(got, want, rtol=0, atol=TOL_MM)


def test_predictor_works_with_jax_not_importable(case_file):
    p = run_without_jax(
        """
        import numpy as np
        import handeye_jax
        from handeye_jax import Predictor
        pred = Predictor.from_result(sys.argv[1])
        pts = json.loads(sys.argv[2])
        out = {s: pred.hand_command(np.array(pts[0]), pts[1], pts[2], stage=s).tolist()
               for s in (1, 2)}
        heavy = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
        try:
            handeye_jax.calibrate
        except ImportError as e:
            missing = str(e)
        print(json.dumps({"out": out, "heavy": heavy, "missing": missing}))
        """,
        str(case_file), json.dumps([a.tolist() for a in PAPER_POINTS]),
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["heavy"] == []
    assert "needs JAX" in doc["missing"]
    pred = Predictor.from_result(case_file)
    for stage in (1, 2):
        want = pred.hand_command(*PAPER_POINTS, stage=stage)
        np.testing.assert_array_equal(doc["out"][str(stage)], want)


def _R_base_hand(phi_deg: float) -> np.ndarray:
    """``Ry(180)·Rz(φ)``, the hand's orientation, written as matrices (independent of the
    predictor's x-y blocks)."""
    c, s = np.cos(np.radians(phi_deg)), np.sin(np.radians(phi_deg))
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return np.diag([-1.0, 1.0, -1.0]) @ Rz


# The camera tilted by 28 deg (alpha_c near its range's end).
TILTED = Case("htm", {"xc": 0.0, "yc": 20.0, "alpha_c": -28.0, "beta_c": 0.0, "gamma_c": 0.0,
                      "xt": 100.0, "yt": 0.0, "alpha_t": 0.0, "beta_t": 0.0, "gamma_t": 0.0,
                      "xp": 0.0, "yp": -10.0},
              {**dict.fromkeys(["X1", "Y1", "theta1", "X2", "Y2", "theta2"], 0.0),
               **dict.fromkeys(["Sx1", "Sy1", "Sx2", "Sy2"], 1.0)},
              (300.0, 300.0, 200.0, 150.0), (0.0, 0.0, 0.0), 90.0, 1,
              ((0.0, 0.0), (0.0, 0.0)))  # fmt: skip


@FAST
@given(
    case=cases(),
    capture_angle=st.floats(-360, 360),
    capture=st.tuples(*[st.floats(-500, 500)] * 3),
    # each point as the camera saw it: where in the picture (fractions of 2·cx, 2·cy) and its
    # depth, mm: in front of the camera, as a photographed point is
    seen=st.lists(st.tuples(st.floats(0, 1), st.floats(0, 1), st.floats(50, 1500)),
                  min_size=1, max_size=5),
    angle=st.floats(-360, 360),
    z_mm=st.tuples(st.floats(-30, 30), st.floats(-60, 0)),
)  # fmt: skip
# Issue 23: points drawn in the base frame 150 mm below a capture 300 mm aside, the camera
# tilted 28 deg away, were behind the camera (negative depth); now they are drawn in its view.
@example(case=TILTED, capture_angle=0.0, capture=(-192.0, 0.0, -500.0),
         seen=[(0.0, 0.5, 150.0), (1.0, 1.0, 60.0)], angle=0.0, z_mm=(0.0, 0.0))  # fmt: skip
def test_a_capture_pose_per_point_turns_the_camera_with_the_hand(
    case, capture_angle, capture, seen, angle, z_mm
):
    """Points photographed from a capture at any hand angle come back where they are
    (stage 1), for each point's own capture pose."""
    frames = case.frames(**{"t_hand_camera_mm.z": z_mm[0], "t_hand_pen_mm.z": z_mm[1]})
    f = frames
    cap = np.array(capture) + [0.0, 0.0, 600.0]
    R_bh = _R_base_hand(float(frames.phi_deg(capture_angle)))
    where, depth = np.array(seen)[:, :2] * [2 * f.cx_px, 2 * f.cy_px], np.array(seen)[:, 2]
    ray = np.c_[(where - [f.cx_px, f.cy_px]) / [f.fx_px, f.fy_px], np.ones(len(seen))]
    X = cap + (depth[:, None] * ray @ f.R_hand_camera.T + f.t_hand_camera_mm) @ R_bh.T
    # the picture of X from the capture, as the camera takes it:
    # p_c = R_hc^T (R_bh^T (X - cap) - t_hc)
    p_c = ((X - cap) @ R_bh - frames.t_hand_camera_mm) @ frames.R_hand_camera
    np.testing.assert_allclose(p_c[:, 2], depth, rtol=1e-9)  # the same point, in front
    uv = p_c[:, :2] / p_c[:, 2:] * [frames.fx_px, frames.fy_px] + [frames.cx_px, frames.cy_px]
    offset = (_R_base_hand(float(frames.phi_deg(angle))) @ frames.t_hand_pen_mm)[:2]
    want = X[:, :2] - offset
    pred = Predictor.from_frames(frames)
    n = len(X)
    got = pred.hand_command(uv, p_c[:, 2], angle, stage=1, capture_position_mm=cap,
                            capture_hand_angle_deg=capture_angle)  # fmt: skip
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-7)
    # per point, as (n, 3) and (n,) arrays: the same as one capture for all
    per_point = pred.hand_command(uv, p_c[:, 2], np.full(n, angle), stage=1,
                                  capture_position_mm=np.tile(cap, (n, 1)),
                                  capture_hand_angle_deg=np.full(n, capture_angle))  # fmt: skip
    np.testing.assert_array_equal(per_point, got)


def test_the_default_capture_pose_is_the_calibrations(case):
    frames = case.frames()
    pred = Predictor.from_frames(frames)
    assert frames.phi_deg(frames.capture_hand_angle_deg) == 0.0
    for stage in (1, 2):
        explicit = pred.hand_command(
            *PAPER_POINTS, stage=stage, capture_position_mm=frames.capture_position_mm,
            capture_hand_angle_deg=frames.capture_hand_angle_deg,
        )  # fmt: skip
        np.testing.assert_array_equal(explicit, pred.hand_command(*PAPER_POINTS, stage=stage))
    # a capture elsewhere moves the commands (stage 1: by the capture's x-y shift)
    shifted = frames.capture_position_mm + [5.0, -3.0, 7.0]
    moved = pred.hand_command(*PAPER_POINTS, stage=1, capture_position_mm=shifted)
    still = pred.hand_command(*PAPER_POINTS, stage=1)
    np.testing.assert_allclose(moved - still, [[5.0, -3.0]] * 3, atol=1e-12)


@FAST
@given(case=cases(), dz=st.tuples(*[st.floats(-100, 100)] * 3), pts=points())
def test_undetermined_components_never_move_x_or_y(case, dz, pts):
    """What the frames call undetermined cannot change a hand command: any value gives the
    same x and y, so none of them is worth a number in the file."""
    known = dict(zip(UNDETERMINED, dz, strict=True))
    a = Predictor.from_frames(case.frames()).hand_command(*pts)
    b = Predictor.from_frames(case.frames(**known)).hand_command(*pts)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", ["htm", "dh"])
def test_no_model_fits_the_components_called_undetermined(name):
    """The models hold them constant: their derivative by every parameter is exactly 0."""
    M = get_model(name)
    lo, hi = M.search_bounds()
    theta = jax.numpy.asarray((lo + hi) / 2)

    def zs(v):
        m = M.from_vector(v)
        return jax.numpy.stack([m.camera_mount()[1][2], m.tablet_pose()[1][2], m.t_hand_pen()[2]])

    assert UNDETERMINED == ("t_hand_camera_mm.z", "t_base_tablet_mm.z", "t_hand_pen_mm.z")
    assert np.all(np.asarray(jax.jit(jax.jacfwd(zs))(theta)) == 0.0)


def test_frames_document_round_trips_and_marks_undetermined_as_null(case):
    frames = case.frames()
    doc = json.loads(json.dumps(frames.to_dict(), allow_nan=False))
    assert doc["T_hand_camera"]["t"] == {"mm": [frames.t_hand_camera_mm[0],
                                                frames.t_hand_camera_mm[1], None],
                                         "determined": [True, True, False]}  # fmt: skip
    assert [u["component"] for u in doc["undetermined"]] == list(UNDETERMINED)
    assert all(u["reason"] for u in doc["undetermined"])
    again = Frames.from_dict(doc)
    for f in dataclasses.fields(Frames):
        a, b = getattr(again, f.name), getattr(frames, f.name)
        if isinstance(b, np.ndarray):
            np.testing.assert_array_equal(a, b)  # NaN where NaN, every other bit equal
        else:
            assert a == b, f.name


def test_hand_command_refuses_bad_arguments(case):
    pred = Predictor.from_frames(case.frames())
    uv, depth, angle = PAPER_POINTS
    bad = [
        ((uv[:, :1], depth, angle), {}, "image_px"),
        ((uv, depth[:2], angle), {}, "depth_mm"),
        ((uv, -depth, angle), {}, "depth_mm"),
        ((uv, depth, [np.nan] * 3), {}, "hand_angle_deg"),
        ((uv, depth, angle), {"stage": 3}, "stage"),
        ((uv, depth, angle), {"axes": "xyz"}, "t_hand_camera_mm.z"),
        ((uv, depth, angle), {"capture_position_mm": [1.0, 2.0]}, "capture_position_mm"),
        ((uv, depth, angle), {"capture_hand_angle_deg": [1.0, 2.0]}, "capture_hand_angle_deg"),
    ]
    for args, kwargs, word in bad:
        with pytest.raises(ValueError, match=word.replace(".", r"\.")):
            pred.hand_command(*args, **kwargs)
    assert pred.axes == "xy"


def _mutations(doc: dict) -> list[tuple[str, callable, str]]:
    def put(path, value):
        def f(d):
            *head, last = path
            for k in head:
                d = d[k]
            d[last] = value

        return f

    return [
        ("frames.T_hand_camera.R", put(["frames", "T_hand_camera", "R", 0, 0], 0.5), "rotation"),
        ("frames.T_hand_camera.t.mm[2]", put(["frames", "T_hand_camera", "t", "mm", 2], 0.0),
         "must be null"),
        ("frames.T_hand_camera.t.mm[0]", put(["frames", "T_hand_camera", "t", "mm", 0], None),
         "must be a number"),
        ("frames.pen_tip.t_hand_pen.determined[2]",
         put(["frames", "pen_tip", "t_hand_pen", "determined", 2], True), "listed"),
        ("frames.hand_angle.sign", put(["frames", "hand_angle", "sign"], 2), "1 or -1"),
        ("frames.camera_px.fx", put(["frames", "camera_px", "fx"], 0), "at least 1"),
        ("frames.stage2.A1.Sx", put(["frames", "stage2", "A1", "Sx"], -1.0), "> 0"),
        ("frames.units.length", put(["frames", "units", "length"], "m"), "'mm'"),
        ("frames.format", put(["frames", "format"], "other/1"), "expected"),
        ("frames.capture.hand_position_mm", put(["frames", "capture", "hand_position_mm"], [1]),
         "array of 3"),
        ("frames.undetermined", put(["frames", "undetermined"], {}), "array"),
        ("frames.extra", put(["frames", "extra"], 1), "unknown key"),
    ]  # fmt: skip


def test_bad_frames_give_one_line_naming_file_and_field(tmp_path, case_file):
    doc = json.loads(case_file.read_text())
    for field, mutate, words in _mutations(doc):
        d = json.loads(json.dumps(doc))
        mutate(d)
        path = tmp_path / "bad.json"
        path.write_text(json.dumps(d))
        with pytest.raises(InputError) as e:
            Predictor.from_result(path)
        msg = str(e.value)
        assert msg.startswith(f"{path}: {field}"), msg
        assert words in msg and "\n" not in msg, msg


def test_bad_files_give_one_line_naming_the_file(tmp_path, case_file):
    doc = json.loads(case_file.read_text())
    old = dict(doc)
    del old["frames"]
    cases_ = {
        "missing.json": (None, "cannot read file"),
        "text.json": ("not json", "not valid JSON"),
        "twice.json": ('{"format": 1, "format": 2}', "duplicate key"),
        "list.json": ("[1, 2]", "JSON object"),
        "other.json": (json.dumps({"format": "x"}), "format"),
        "old.json": (json.dumps(old), "handeye-jax export"),
    }
    for name, (text, words) in cases_.items():
        path = tmp_path / name
        if text is not None:
            path.write_text(text)
        with pytest.raises(InputError) as e:
            Predictor.from_result(path)
        assert str(e.value).startswith(str(path)) and words in str(e.value), str(e.value)
    big = tmp_path / "big.json"
    with open(big, "wb") as f:
        f.truncate(65 * 1024 * 1024)  # sparse: nothing is written
    with pytest.raises(InputError, match="larger than 64 MiB"):
        Predictor.from_result(big)


def test_cli_predict_uses_the_frames_and_reads_older_results(tmp_path, case_file, capsys):
    csv = tmp_path / "points.csv"
    csv.write_text("u,v,depth,hand_angle\n" + "".join(
        f"{u},{v},{d},{a}\n" for (u, v), d, a in zip(*PAPER_POINTS, strict=True)))  # fmt: skip
    assert main(["predict", str(case_file), str(csv)]) == 0
    with_frames = capsys.readouterr().out
    want = Predictor.from_result(case_file).hand_command(*PAPER_POINTS)
    rows = [line.split(",")[-2:] for line in with_frames.strip().splitlines()[1:]]
    np.testing.assert_allclose(np.array(rows, dtype=float), want, atol=1e-6)
    # an older result, without frames: the JAX side computes them from the parameters
    doc = json.loads(case_file.read_text())
    del doc["frames"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(doc))
    assert main(["predict", str(old), str(csv)]) == 0
    assert capsys.readouterr().out == with_frames
    # frames that disagree with the parameters: refused, not silently one or the other
    doc = json.loads(case_file.read_text())
    doc["frames"]["pen_tip"]["t_hand_pen"]["mm"][0] += 0.5
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(doc))
    assert main(["predict", str(edited), str(csv)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"handeye-jax: error: {edited}: frames: disagrees")
    assert err.count("\n") == 1
    with pytest.raises(InputError):
        load_frames(edited)


def test_cli_predict_runs_without_jax_on_a_result_as_written(tmp_path, case_file):
    """The CLI's predict reads a result file as calibrate wrote it with NumPy alone (JAX,
    OpenCV, matplotlib and jaxtyping not even importable), and gives the JAX path's numbers."""
    csv = tmp_path / "points.csv"
    csv.write_text("u,v,depth,hand_angle\n" + "".join(
        f"{u},{v},{d},{a}\n" for (u, v), d, a in zip(*PAPER_POINTS, strict=True)))  # fmt: skip
    code = """
        from handeye_jax.cli import main
        code = main(sys.argv[1:])
        heavy = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
        print(json.dumps({"code": code, "heavy": heavy}), file=sys.stderr)
        """
    for stage in (1, 2):
        p = run_without_jax(code, "predict", str(case_file), str(csv), "--stage", str(stage))
        assert p.returncode == 0, p.stderr
        assert json.loads(p.stderr.splitlines()[-1]) == {"code": 0, "heavy": []}
        rows = [line.split(",")[-2:] for line in p.stdout.strip().splitlines()[1:]]
        checked = Predictor.from_frames(load_frames(case_file))  # JAX's check of the frames
        want = checked.hand_command(*PAPER_POINTS, stage=stage)
        np.testing.assert_allclose(np.array(rows, dtype=float), want, rtol=0, atol=1e-6)  # µm


def test_only_a_file_as_written_skips_the_check_of_its_frames(tmp_path, case_file):
    """``stored_frames`` trusts the frames while the content digest matches (indentation does
    not matter); any edit, of the frames or of anything else, sends the file to the check."""
    from handeye_jax.robot import stored_frames

    doc = json.loads(case_file.read_text())
    assert re.fullmatch(r"[0-9a-f]{64}", doc["content_sha256"])
    assert stored_frames(case_file) is not None
    variants = {"reindented": (lambda d: None, True),
                "frames": (lambda d: d["frames"]["pen_tip"]["t_hand_pen"]["mm"].__setitem__(
                    0, d["frames"]["pen_tip"]["t_hand_pen"]["mm"][0] + 1e-6), False),
                "params": (lambda d: d["stage1"]["params"].__setitem__("xc", 0.0), False),
                "other": (lambda d: d.__setitem__("dataset", "renamed"), False),
                "digest": (lambda d: d.__setitem__("content_sha256", "0" * 64), False),
                "no digest": (lambda d: d.pop("content_sha256"), False)}  # fmt: skip
    for name, (edit, trusted) in variants.items():
        d = json.loads(case_file.read_text())
        edit(d)
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(d, indent=4))
        assert (stored_frames(path) is not None) is trusted, name
    # a file the writer did not write: no shortcut, the full reader reports it
    (tmp_path / "broken.json").write_text("{not json")
    assert stored_frames(tmp_path / "broken.json") is None


def test_predictor_benchmark_runs_in_process(capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["predictor.py", "--quick"])
    runpy.run_path(str(ROOT / "benchmarks" / "predictor.py"), run_name="__main__")
    out = capsys.readouterr().out
    assert "| numpy Predictor |" in out and "| JAX path (jit) |" in out
    assert "µs per point" in out and "max |numpy − JAX|" in out


class _Robot:
    def __init__(self):
        self.moves = []

    def move_to(self, position_mm, hand_angle_deg):
        self.moves.append((np.asarray(position_mm, dtype=float), float(hand_angle_deg)))


def test_the_readme_pick_loop_touches_what_the_predictor_says(case_file):
    """docs/use-on-the-robot.md's examples run as written, the pick loop with a fake
    robot and camera: it captures from the calibration's pose and goes to each command."""
    section = (ROOT / "docs" / "use-on-the-robot.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 2
    import handeye_jax as hj

    ns = {"hj": hj}
    code = "\n".join(blocks).replace('"paper.result.json"', repr(str(case_file)))
    exec(compile(code, "docs/use-on-the-robot.md", "exec"), ns)
    assert ns["xy_mm"].shape == (1, 2)
    uv, depth, angle = PAPER_POINTS
    robot = _Robot()
    camera = type("Camera", (), {"capture": lambda self: "picture"})()
    found = lambda picture: (uv, depth) if picture == "picture" else None  # noqa: E731
    predictor = ns["pred"]
    ns["pick_loop"](robot, camera, found, predictor, hand_angle_deg=45.0, touch_z_mm=118.0)
    frames = predictor.frames
    assert len(robot.moves) == 1 + len(uv)
    np.testing.assert_array_equal(robot.moves[0][0], frames.capture_position_mm)
    assert robot.moves[0][1] == frames.capture_hand_angle_deg
    want = predictor.hand_command(uv, depth, np.full(3, 45.0))
    for (position, hand_angle), (x, y) in zip(robot.moves[1:], want, strict=True):
        np.testing.assert_array_equal(position, [x, y, 118.0])
        assert hand_angle == 45.0
