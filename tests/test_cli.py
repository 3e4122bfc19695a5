"""The command line: the main job, prediction, and one-line errors that write nothing."""

import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from handeye_jax import load_result
from handeye_jax.cli import main
from tests.common import FAST, PAPER, ROOT


@pytest.fixture(scope="session")
def result_file(paper_result_file):
    return paper_result_file


def test_calibrate_writes_a_loadable_result(result_file, capsys):
    doc = json.loads(result_file.read_text())
    assert doc["format"] == "handeye-jax.result/1"
    assert doc["model"] == "htm" and doc["dataset"] == "paper2023"
    for stage in ("stage1", "stage2"):
        assert set(doc[stage]) >= {"F", "f1", "f2", "params", "residuals_mm"}
        assert len(doc[stage]["residuals_mm"]) == 9
    assert set(doc["timings_s"]) >= {"total", "stage1_de", "stage2_de"}
    r = load_result(result_file)
    assert r.stage1.params == doc["stage1"]["params"]


def test_calibrate_summary_names_units(tmp_path, capsys):
    assert main(["calibrate", str(PAPER), *FAST, "--verbose"]) == 0
    out = capsys.readouterr().out
    assert "stage 1: F = " in out and "stage 2: F = " in out and " mm" in out
    assert "xc" in out and "alpha_t" in out and "deg" in out and "time:" in out


def test_predict_adds_hand_commands(result_file, tmp_path, capsys):
    pts = tmp_path / "points.csv"
    pts.write_text("u,v,depth,hand_angle\n338,244,169.2,90\n119,105,168.2,0\n")
    out = tmp_path / "out.csv"
    assert main(["predict", str(result_file), str(pts), "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[0] == "u,v,depth,hand_angle,hand_x,hand_y"
    xy = np.array([[float(v) for v in line.split(",")[4:]] for line in lines[1:]])
    r = load_result(result_file)
    want = r.predict(np.array([[338, 244], [119, 105.0]]), np.array([169.2, 168.2]),
                     np.array([90.0, 0.0]))  # fmt: skip
    np.testing.assert_allclose(xy, want, atol=1e-6)
    # The fitted hand positions of the paper are within a few mm of landmark 4 and 0's.
    assert np.linalg.norm(xy[0] - [327, -17]) < 3 and np.linalg.norm(xy[1] - [289, 1]) < 3
    capsys.readouterr()
    assert main(["predict", str(result_file), str(pts), "--stage", "1"]) == 0
    stage1 = capsys.readouterr().out.splitlines()
    assert stage1[0].endswith("hand_x,hand_y") and len(stage1) == 3


def _bad_dataset(tmp_path, old, new):
    text = PAPER.read_text()
    assert old in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(old, new, 1))
    return p


BAD_DATASETS = [
    ("depth = 169.2", "depth = -1.0", "landmarks[4].depth"),
    ("depth = 169.2", "depth = nan", "landmarks[4].depth"),
    ("ppi = 267.0", "ppi = 0.0", "tablet.ppi"),
    ("fx = 617.7", "fox = 617.7", "camera"),
    ('format = "handeye-jax.dataset/1"', 'format = "other/2"', "format"),
    ("image_px = [338.0, 244.0]", "image_px = [338.0]", "landmarks[4].image_px"),
    # nonsense that calibrated to F = 64 m with exit 0 (issue 16, section 3)
    ("image_px = [338.0, 244.0]", "image_px = [1e6, -1e6]", "landmarks[4].image_px"),
    ("ppi = 267.0\nscale = 2.0", "ppi = 1\nscale = 100", "tablet: one tablet px is"),
]


@pytest.mark.parametrize("old,new,field", BAD_DATASETS)
def test_bad_dataset_gives_one_line_and_writes_nothing(tmp_path, capsys, old, new, field):
    bad = _bad_dataset(tmp_path, old, new)
    out = tmp_path / "result.json"
    assert main(["calibrate", str(bad), "--out", str(out), *FAST]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert str(bad) in err and field in err
    assert not out.exists()


def test_existing_output_survives_a_failed_run(tmp_path, capsys):
    bad = _bad_dataset(tmp_path, "depth = 169.2", "depth = 0.0")
    out = tmp_path / "result.json"
    out.write_text("precious")
    assert main(["calibrate", str(bad), "--out", str(out), *FAST]) == 2
    assert out.read_text() == "precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml", "result.json"]


def test_search_range_errors(tmp_path, capsys):
    text = PAPER.read_text() + "\n[search]\nxt = [250.0, 100.0]\n"
    bad = tmp_path / "range.toml"
    bad.write_text(text)
    assert main(["calibrate", str(bad), *FAST]) == 2
    assert "search.xt" in capsys.readouterr().err
    bad.write_text(PAPER.read_text() + "\n[search]\nbogus = [0.0, 1.0]\n")
    assert main(["calibrate", str(bad), *FAST]) == 2
    assert "bogus" in capsys.readouterr().err


def test_missing_and_unreadable_files(tmp_path, capsys):
    assert main(["calibrate", str(tmp_path / "nope.toml"), *FAST]) == 2
    assert "nope.toml" in capsys.readouterr().err
    binary = tmp_path / "junk.toml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    assert main(["calibrate", str(binary), *FAST]) == 2
    assert "junk.toml" in capsys.readouterr().err
    assert main(["calibrate", str(PAPER), "--out", str(tmp_path / "no" / "r.json"), *FAST]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_bad_result_and_points_files(result_file, tmp_path, capsys):
    pts = tmp_path / "p.csv"
    pts.write_text("u,v,depth,hand_angle\n1,2,3,4\n")
    doc = json.loads(result_file.read_text())
    doc["stage1"]["params"]["xc"] = "oops"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    assert main(["predict", str(bad), str(pts)]) == 2
    assert "stage1.params.xc" in capsys.readouterr().err
    bad.write_text("{not json")
    assert main(["predict", str(bad), str(pts)]) == 2
    assert "not valid JSON" in capsys.readouterr().err
    for text, field in [
        ("x,y\n1,2\n", "header"),
        ("u,v,depth,hand_angle\n1,2,-3,4\n", "line 2.depth"),
        ("u,v,depth,hand_angle\n1,nan,3,4\n", "line 2.v"),
        ("u,v,depth,hand_angle\n1,2,3\n", "line 2"),
        ("u,v,depth,hand_angle\n", "rows"),
        ("u,v,depth,hand_angle\n1,2,1e308,4\n", "line 2.depth"),
        ("u,v,depth,hand_angle\n3_38,2,3,4\n", "line 2.u"),
        ("u,v,depth,hand_angle,u\n1,2,3,4,5\n", "header"),
    ]:
        pts.write_text(text)
        out = tmp_path / "o.csv"
        assert main(["predict", str(result_file), str(pts), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert field in err and str(pts) in err and len(err.strip().splitlines()) == 1
        assert not out.exists()


def test_a_fit_that_is_not_finite_stops_with_one_line_and_writes_nothing(
    tmp_path, capsys, monkeypatch
):
    import dataclasses
    import importlib

    cal = importlib.import_module("handeye_jax.calibration._stage_result")
    fit = cal._stage_result  # the real fit, then its F made NaN: what absurd data would give
    monkeypatch.setattr(cal, "_stage_result", lambda *a: dataclasses.replace(fit(*a), F=np.nan))
    out = tmp_path / "r.json"
    assert main(["calibrate", str(PAPER), *FAST, "--no-diagnostics", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(PAPER) in err
    assert "stage 1's fit is not finite (F = nan mm)" in err
    assert not out.exists()


def test_a_points_csv_with_a_byte_order_mark_reads_as_without(result_file, tmp_path, capsys):
    text = "u,v,depth,hand_angle\n338,244,169.2,90\n"
    outs = []
    for name, data in (("plain.csv", text.encode()), ("bom.csv", b"\xef\xbb\xbf" + text.encode())):
        (tmp_path / name).write_bytes(data)
        assert main(["predict", str(result_file), str(tmp_path / name)]) == 0
        outs.append(capsys.readouterr().out)
    assert outs[0] == outs[1] and outs[0].startswith("u,v,depth,hand_angle,hand_x,hand_y\n")


@pytest.mark.parametrize("args", [["--population", "2"], ["--generations", "0"],
                                  ["--model", "nope"], ["--seed", "x"],
                                  ["--seed", str(2**63)]])  # fmt: skip
def test_bad_arguments_are_one_line(args, capsys):
    with pytest.raises(SystemExit) as e:
        main(["calibrate", str(PAPER), *args])
    assert e.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


FULL_WIDTH_ONE = "\uff11"  # Python's int() and float() read it as 1


@pytest.mark.parametrize(
    "argv,option,says",
    [
        (["calibrate", str(PAPER), "--seed", FULL_WIDTH_ONE], "--seed", "not a whole number"),
        (["calibrate", str(PAPER), "--population", "1_000"], "--population", "not a whole"),
        (["calibrate", str(PAPER), "--loss-scale-mm", FULL_WIDTH_ONE], "--loss-scale-mm", "not a"),
        (["calibrate", str(PAPER), "--population", "1000000"], "--population", "at most 100,000"),
        (["calibrate", str(PAPER), "--generations", "1000000"], "--generations", "at most 100,000"),
        (["predict", "r.json", "p.csv", "--stage", FULL_WIDTH_ONE], "--stage", "not a whole"),
        (["tablet", "--ppi", FULL_WIDTH_ONE], "--ppi", "not a number"),
        (["tablet", "--scale", "nan"], "--scale", "must be a finite number > 0"),
    ],
)
def test_numbers_on_the_command_line_are_ascii_and_bounded(capsys, argv, option, says):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"argument {option}: " in err and says in err, err


def test_full_width_digits_in_a_points_csv_are_not_numbers(result_file, tmp_path, capsys):
    pts = tmp_path / "p.csv"
    pts.write_text(f"u,v,depth,hand_angle\n338,244,169.2,90\n{FULL_WIDTH_ONE}19,105,168.2,0\n")
    assert main(["predict", str(result_file), str(pts)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{pts}: line 3.u: not a number: '\uff1119'" in err, err


def test_a_fit_that_does_not_fit_the_data_is_plainly_warned_about(tmp_path, capsys):
    # Values within every limit, but hand positions no rig reaches from these image points.
    text = PAPER.read_text()
    for old in ("hand_xy = [289.0, 1.0]", "hand_xy = [403.0, 14.0]"):
        assert old in text
        text = text.replace(old, "hand_xy = [5000.0, -7000.0]")
    bad = tmp_path / "far.toml"
    bad.write_text(text)
    out = tmp_path / "far.json"
    assert main(["calibrate", str(bad), "--out", str(out), "--no-diagnostics", *FAST]) == 0
    summary = capsys.readouterr().out
    # Read as written: the result's own reach check may refuse a fit this far off the data.
    warning = next(w for w in json.loads(out.read_text())["warnings"]
                   if w.startswith("the data do not fit"))  # fmt: skip
    assert warning in summary and "do not use this result" in warning
    F = float(warning.split("F = ")[1].split(" mm")[0])
    assert F > 100


def test_console_script_exit_keeps_every_output(tmp_path):
    # The console script leaves by os._exit: its streams and the result must be complete.
    out = tmp_path / "r.json"
    # The suite's caches (tests/conftest.py), as the closed-pipe test below: the same programs.
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    for name in ("HANDEYE_JAX_DEBUG", "PYTHONUNBUFFERED"):  # block-buffered, as for most users
        env.pop(name, None)
    p = subprocess.run([sys.executable, "-m", "handeye_jax.cli", "calibrate", str(PAPER),
                        "--population", "40", "--generations", "5", "--no-diagnostics",
                        "--out", str(out)], capture_output=True, text=True, env=env)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert f"saved: {out}" in p.stdout and p.stdout.rstrip().splitlines()[-1].startswith("time:")
    assert "stage 1 DE" in p.stderr  # the progress bars
    assert load_result(out).stage1.F > 0


def test_a_closed_pipe_on_stdout_keeps_the_result_and_says_nothing(tmp_path):
    # `handeye-jax calibrate ... --out r.json | head -1`: the reader leaves before the summary.
    out = tmp_path / "r.json"
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    p = subprocess.Popen([sys.executable, "-m", "handeye_jax.cli", "calibrate", str(PAPER),
                          "--population", "40", "--generations", "5", "--no-diagnostics",
                          "--quiet", "--out", str(out)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, env=env)  # fmt: skip
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait() == 141 and err == "", err
    assert load_result(out).stage1.F > 0


def test_console_script_runs_without_traceback(tmp_path):
    bad = _bad_dataset(tmp_path, "scale = 2.0", "scale = -2.0")
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    p = subprocess.run([sys.executable, "-m", "handeye_jax.cli", "calibrate", str(bad)],
                       capture_output=True, text=True, env=env)  # fmt: skip
    assert p.returncode == 2
    assert "Traceback" not in p.stderr and "tablet.scale" in p.stderr


def test_too_few_landmarks(tmp_path, capsys):
    text = PAPER.read_text()
    head, *landmarks = text.split("[[landmarks]]")
    bad = tmp_path / "two.toml"
    bad.write_text(head + "[[landmarks]]" + "[[landmarks]]".join(landmarks[:2]))
    assert main(["calibrate", str(bad), *FAST]) == 2
    err = capsys.readouterr().err
    assert "landmarks" in err and "at least" in err and len(err.strip().splitlines()) == 1


def test_compilation_cache_goes_where_asked_and_can_be_turned_off(tmp_path, paper_result_file):
    # Two commands that compile programs of their own, quicker than a calibration: report (a
    # stored program of its own) and export (JAX's, to check the frames).
    cli = [sys.executable, "-m", "handeye_jax.cli"]
    cache = tmp_path / "xla-cache"
    env = dict(os.environ, HANDEYE_JAX_CACHE_DIR=str(cache))
    report = [*cli, "report", str(paper_result_file), "--out", str(tmp_path / "figures")]
    p = subprocess.run(report, capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr[-2000:]
    assert cache.is_dir() and any(cache.iterdir())
    assert any((cache / "programs").glob("*.program"))  # jax.export's programs, beside XLA's
    home = tmp_path / "home"
    env = dict(os.environ, HANDEYE_JAX_CACHE_DIR="off", HOME=str(home), XDG_CACHE_HOME="")
    export = [*cli, "export", str(paper_result_file), "--format", "json"]
    p = subprocess.run(export, capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr[-2000:]
    assert not (home / ".cache" / "handeye-jax").exists()


def test_detect_in_place_keeps_the_users_comments(tmp_path, capsys):
    from handeye_jax import PRESETS, draw_truth, load_dataset, simulate, write_twin

    write_twin(simulate(draw_truth(4), PRESETS["paper"], 4, n_heldout=1), tmp_path)
    detected = load_dataset(tmp_path / "dataset.toml")
    text = (tmp_path / "dataset.toml").read_text()
    # The user's file: comments of every kind, and image_px and depth not measured yet.
    text = re.sub(r"image_px = \[[^]]*\]", "image_px = [0.0, 0.0]  # to be detected", text)
    text = re.sub(r"depth = [0-9.]+", "depth = 1  # to be detected", text)
    text = "# rig of the lab, 3rd floor\n" + text.replace("[tablet]", "# measured\n[tablet]")
    text = text.replace("[camera]", "[camera]  # from the factory", 1) + "# the end\n"
    ds_path = tmp_path / "mine.toml"
    ds_path.write_text(text)
    capture, depth = str(tmp_path / "capture.png"), str(tmp_path / "depth.png")
    assert main(["detect", capture, depth, "--dataset", str(ds_path)]) == 0
    assert "previous file kept as" in capsys.readouterr().out
    after = ds_path.read_text()
    comment_lines = [line for line in text.splitlines() if "#" in line]
    assert len(comment_lines) >= 2 * 9 + 4
    for line in text.splitlines():  # every line is there, with a new value where detected
        if "# to be detected" not in line:
            assert line in after.splitlines(), line
    assert after.count("# to be detected") == 2 * 9
    assert load_dataset(ds_path) == detected
    (backup,) = tmp_path.glob("mine.toml.*.bak")
    assert backup.read_text() == text
    # Detected again: the file already holds these values, nothing is written.
    before = ds_path.read_bytes()
    assert main(["detect", capture, depth, "--dataset", str(ds_path)]) == 0
    assert "already holds them" in capsys.readouterr().out
    assert ds_path.read_bytes() == before
    (backup,) = tmp_path.glob("mine.toml.*.bak")
    assert backup.read_text() == text


# -- Ctrl-C, --version, help ---------------------------------------------------------------

INTERRUPTED = "handeye-jax: interrupted; nothing was written"
#: Moments of a run, each recognised on its stderr: during the imports (seen with
#: ``-X importtime``), in stage 1's DE, after stage 2's DE (polish, diagnostics). The last
#: moment, after the summary and before the write, is the in-process test below.
CTRL_C_MOMENTS = {
    "importing numpy": (["-X", "importtime"], r"\|\s+numpy\n"),
    "stage 1 DE": ([], r"stage 1 DE"),
    "after stage 2 DE": ([], r"stage 2 DE[^\n]*\n"),
}


def _ctrl_c_when(tmp_path, python_flags, pattern, signum=None):
    """Start ``calibrate --out`` over an existing file, send SIGINT (or ``signum``) when
    stderr matches."""
    import signal
    import threading
    import time

    out = tmp_path / "result.json"
    out.write_text("precious\n")
    cmd = [sys.executable, *python_flags, "-m", "handeye_jax.cli", "calibrate", str(PAPER),
           "--population", "40", "--generations", "70", "--out", str(out)]  # fmt: skip
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    chunks: list[bytes] = []
    reader = threading.Thread(target=lambda: chunks.extend(iter(lambda: p.stderr.read1(), b"")))
    reader.start()
    deadline = time.monotonic() + 120
    while not re.search(pattern, b"".join(chunks).decode(errors="replace")):
        assert p.poll() is None, f"the run ended before {pattern!r}"
        assert time.monotonic() < deadline
        time.sleep(0.005)
    p.send_signal(signal.SIGINT if signum is None else signum)
    stdout = p.stdout.read()
    p.wait(timeout=120)
    reader.join()
    err = b"".join(chunks).decode()
    lines = [s for s in re.split(r"[\r\n]+", err) if s.strip() and not s.startswith("import time")]
    return p.returncode, stdout.decode(), err, lines, out


@pytest.mark.slow
@pytest.mark.parametrize("moment", CTRL_C_MOMENTS)
def test_ctrl_c_at_any_moment_exits_130_and_keeps_the_out_file(tmp_path, moment):
    rc, _, err, lines, out = _ctrl_c_when(tmp_path, *CTRL_C_MOMENTS[moment])
    assert rc == 130, err[-2000:]
    assert lines[-1] == INTERRUPTED
    assert "Traceback" not in err and "Exception ignored" not in err
    assert out.read_text() == "precious\n"
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]  # no temporary file left


@pytest.mark.parametrize("moment", ["importing numpy", "stage 1 DE"])
def test_sigterm_is_handled_as_ctrl_c_is_exit_143_and_the_out_file_kept(tmp_path, moment):
    import signal

    rc, _, err, lines, out = _ctrl_c_when(tmp_path, *CTRL_C_MOMENTS[moment], signal.SIGTERM)
    assert rc == 143, err[-2000:]
    assert lines[-1] == "handeye-jax: terminated; nothing was written"
    assert "Traceback" not in err and "Exception ignored" not in err
    assert out.read_text() == "precious\n"
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]  # no temporary file left


def test_a_ctrl_c_that_a_callback_swallowed_still_stops_before_the_write(
    tmp_path, capsys, monkeypatch
):
    import gc
    import signal

    import handeye_jax.calibration

    to_json = handeye_jax.calibration.result_to_json

    def swallowing(result):  # the last step before the write
        # gc off while the handler runs, so no gc callback (hypothesis's) runs inside it; the
        # traceback once blamed on this came from execnet's end-of-run SIGINT (conftest.py)
        gc.disable()
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            pass  # as JAX's _xla_gc_callback swallows it
        finally:
            gc.enable()
        return to_json(result)

    monkeypatch.setattr(handeye_jax.calibration, "result_to_json", swallowing)  # the CLI finds it
    out = tmp_path / "result.json"
    out.write_text("precious\n")
    assert main(["calibrate", str(PAPER), *FAST, "--no-diagnostics", "--out", str(out)]) == 130
    assert capsys.readouterr().err.strip() == INTERRUPTED
    assert out.read_text() == "precious\n"
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]


def test_version_is_the_installed_packages(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out == f"handeye-jax {version('handeye-jax')}\n"


def _subcommands():
    import argparse

    from handeye_jax.cli import build_parser

    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices


SUBCOMMANDS = ["calibrate", "calibrate-batch", "predict", "report", "tablet", "simulate",
               "detect", "evaluate", "export", "convert", "plan", "plan-acquisition", "poses",
               "intrinsics"]  # fmt: skip


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_every_option_has_help_that_states_its_default(name):
    parser = _subcommands()[name]
    formatter = parser._get_formatter()
    for action in parser._actions:
        if action.help == "show this help message and exit":
            continue
        text = formatter._expand_help(action) if action.help else ""
        assert len(text) > 10, f"{name} {action.dest}: no help"
        if not action.option_strings or action.required:
            continue
        assert "default" in text.lower(), f"{name} {action.option_strings[0]}: {text!r}"
        d = action.default
        if d not in (None, False):
            shown = {str(d), f"{d:g}"} if isinstance(d, float) else {str(d)}
            assert any(s in text for s in shown), f"{name} {action.option_strings[0]}: {text!r}"


def test_the_subcommands_are_the_ones_checked_above():
    assert sorted(_subcommands()) == sorted(SUBCOMMANDS)


def test_help_of_every_subcommand_imports_nothing_heavy():
    """``--help`` stays quick: no JAX, matplotlib, OpenCV or tomlkit (issue 19, section 3), nor
    the package metadata's reader."""
    code = """
import contextlib, io, json, sys
from handeye_jax.cli import main
heavy, shown = {}, {}
for name in sys.argv[1:]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        main([name, "--help"] if name else ["--help"])
    shown[name] = out.getvalue()
    heavy[name] = sorted({m.split(".")[0] for m in sys.modules} & {"jax", "jaxlib",
                         "matplotlib", "cv2", "tomlkit", "equinox", "optimistix"})
print(json.dumps({"heavy": heavy, "shown": shown, "metadata": "importlib.metadata" in sys.modules}))
"""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.run([sys.executable, "-c", code, "", *SUBCOMMANDS], capture_output=True,
                       text=True, timeout=120, env=env)  # fmt: skip
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["heavy"] == {name: [] for name in ["", *SUBCOMMANDS]}
    assert not doc["metadata"]  # the version is read only for --version
    for name in SUBCOMMANDS:
        assert doc["shown"][name].startswith(f"usage: handeye-jax {name} ")
        assert "--help" in doc["shown"][name] and len(doc["shown"][name]) > 200


def test_the_models_the_command_line_offers_are_the_registry():
    from handeye_jax.cli import MODELS
    from handeye_jax.models import model_registry

    # Models defined elsewhere (a test's one-file model) register too; the CLI offers the shipped.
    shipped = [
        n for n, cls in model_registry().items() if cls.__module__.startswith("handeye_jax.")
    ]
    assert sorted(MODELS) == sorted(shipped) and len(shipped) >= 2
