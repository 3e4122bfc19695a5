"""The tablet server without a browser: strict posts, files never corrupted, one-line errors."""

import errno
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from test_dataset import commented_paper_text, comments_of

from handeye_jax import load_dataset
from handeye_jax.cli import main
from handeye_jax.tablet import grid_targets, load_targets, make_server, serve
from handeye_jax.tablet import server as server_mod
from handeye_jax.tablet.posts import MAX_BODY_BYTES
from handeye_jax.tablet.trials import format_summary

PAPER = Path(__file__).resolve().parents[1] / "data" / "paper2023.toml"


def start(ds, **kwargs):
    """A running server over ``ds`` on a free port (unless ``port`` is given)."""
    server = make_server(ds, **{"port": 0, "quiet": True, **kwargs})
    threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True).start()
    return server


def stop(server):
    server.shutdown()
    server.server_close()


@pytest.fixture
def served(tmp_path):
    """A server on a free port over a copy of the paper's dataset; yields (url, dataset path)."""
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    server = start(ds)
    yield server.url, ds
    stop(server)


def request(url, body=None, headers=None, method=None):
    """(status, JSON answer) of a request; ``body`` is bytes or a JSON-able object."""
    data = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
    h = {"Content-Type": "application/json"} if data is not None else {}
    h.update(headers or {})
    req = urllib.request.Request(url, data=data, headers=h, method=method)
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def calibration_body(tablet_px, errors, run_id="run-1"):
    return {
        "run_id": run_id,
        "touches": [
            {"m": m, "tablet_px": list(xy), "touch_error_px": list(e), "pointer_type": "pen"}
            for m, (xy, e) in enumerate(zip(tablet_px, errors, strict=True))
        ],
    }


def test_valid_calibration_post_writes_dataset_and_backup(served):
    url, ds = served
    before = ds.read_bytes()
    old = load_dataset(ds)
    errors = np.arange(18, dtype=float).reshape(9, 2) / 4 - 2
    status, doc = request(url + "api/calibration", calibration_body(old.tablet_px.tolist(), errors))
    assert status == 200 and doc["written"] is True
    new = load_dataset(ds)
    np.testing.assert_array_equal(new.touch_error_px, errors)
    assert new == old.replace(touch_error_px=errors)  # nothing else changed
    assert (ds.parent / "rig.toml.bak").read_bytes() == before
    # A resend (the answer was lost) writes nothing and keeps the backup of the original.
    status, doc = request(url + "api/calibration", calibration_body(old.tablet_px.tolist(), errors))
    assert status == 200 and doc["written"] is False
    assert (ds.parent / "rig.toml.bak").read_bytes() == before


def _bad_bodies(tablet_px):
    good = calibration_body(tablet_px, [[1.0, -1.0]] * len(tablet_px))

    def with_touch(i, **change):
        body = json.loads(json.dumps(good))
        body["touches"][i].update(change)
        return body

    short = json.loads(json.dumps(good))
    short["touches"].pop()
    moved = with_touch(3, tablet_px=[1041.0, 350.0])
    return [
        (400, b"{not json"),
        (400, b"[1, 2]"),
        (400, b'{"run_id": "r", "touches": [{"m": 0, "tablet_px": [NaN, 1]}]}'),
        (400, {**good, "extra": 1}),
        (400, short),
        (400, with_touch(2, m=5)),
        (400, with_touch(4, touch_error_px=[1.0])),
        (400, with_touch(4, touch_error_px=[1e300, 0.0])),
        (400, with_touch(4, touch_error_px=["1", 0.0])),
        (400, with_touch(4, touch_error_px=[True, 0.0])),
        (400, with_touch(0, pointer_type="laser")),
        (400, with_touch(0, tablet_px=[-5.0, 10.0])),
        (400, {**good, "run_id": ""}),
        (409, moved),
    ]


def test_a_calibration_post_keeps_the_users_comments(tmp_path):
    ds = tmp_path / "rig.toml"
    ds.write_text(commented_paper_text())
    before = ds.read_bytes()
    old = load_dataset(ds)
    server = start(ds)
    try:
        tablet_px = old.tablet_px.tolist()
        moved = calibration_body([[1.0, 1.0], *tablet_px[1:]], [[0.0, 0.0]] * 9)
        status, _ = request(server.url + "api/calibration", moved)
        assert status == 409 and ds.read_bytes() == before  # refused: byte-identical
        errors = np.round(np.random.default_rng(5).uniform(-6, 6, (9, 2)), 3)
        status, doc = request(server.url + "api/calibration", calibration_body(tablet_px, errors))
        assert status == 200 and doc["written"] is True
    finally:
        stop(server)
    after = ds.read_text()
    assert comments_of(after) == comments_of(before.decode())
    assert "# end of file: keep this note" in after and "  -70,  # y" in after
    assert load_dataset(ds) == old.replace(touch_error_px=errors)
    assert (tmp_path / "rig.toml.bak").read_bytes() == before


def test_touches_of_another_datasets_landmarks_are_refused(served):
    url, ds = served
    before = ds.read_bytes()
    status, session = request(url + "api/session")
    tablet_px = session["dataset"]["tablet_px"]
    body = calibration_body(tablet_px, [[1.0, 2.0]] * 9)
    status, doc = request(url + "api/calibration", {**body, "key": "0123456789abcdef"})
    assert status == 409 and doc["field"] == "key" and "another dataset" in doc["error"]
    assert ds.read_bytes() == before
    status, doc = request(url + "api/calibration", {**body, "key": ""})
    assert status == 400 and doc["field"] == "key"
    status, doc = request(url + "api/calibration", {**body, "key": session["dataset"]["key"]})
    assert status == 200 and doc["written"] is True
    np.testing.assert_array_equal(load_dataset(ds).touch_error_px, [[1.0, 2.0]] * 9)


def test_bad_posts_get_4xx_and_leave_the_dataset_byte_identical(served):
    url, ds = served
    before = ds.read_bytes()
    tablet_px = load_dataset(ds).tablet_px.tolist()
    for status, body in _bad_bodies(tablet_px):
        got, doc = request(url + "api/calibration", body)
        assert got == status, (body, doc)
        assert doc["error"] and "field" in doc
    got, doc = request(url + "api/calibration", b"x" * (MAX_BODY_BYTES + 1))
    assert got == 413 and "limit" in doc["error"]
    got, doc = request(url + "api/calibration", b"{}", headers={"Content-Type": "text/plain"})
    assert got == 415
    got, doc = request(url + "api/nothing", b"{}")
    assert got == 404
    assert ds.read_bytes() == before
    assert sorted(p.name for p in ds.parent.iterdir()) == ["rig.toml"]  # no backup, no temp


def test_a_dataset_broken_on_disk_is_refused_not_overwritten(served):
    url, ds = served
    tablet_px = load_dataset(ds).tablet_px.tolist()
    broken = ds.read_bytes().replace(b"depth = 168.2", b"depth = -168.2")
    ds.write_bytes(broken)
    status, doc = request(url + "api/calibration", calibration_body(tablet_px, [[0, 0]] * 9))
    assert status == 409 and "landmarks[0].depth" in doc["error"]
    assert ds.read_bytes() == broken


def test_evaluation_trials_saved_once_with_px_and_mm(served):
    url, ds = served
    targets = grid_targets(2, 1, 100.0, 200.0, 300.0, 200.0)
    touched = targets + [[3.0, 4.0], [0.0, -1.0]]
    body = {
        "run_id": "t-1",
        "label": "stage 1",
        "targets": "grid",
        "touches": [
            {"m": m, "target_px": t.tolist(), "touch_px": p.tolist(), "pointer_type": "pen"}
            for m, (t, p) in enumerate(zip(targets, touched, strict=True))
        ],
    }
    for _ in range(2):  # the second is a resend of the same trial
        status, doc = request(url + "api/evaluation", body)
        assert status == 200 and doc["trial"] == 1
    saved = json.loads((ds.parent / "rig.trials.json").read_text())
    assert len(saved["trials"]) == 1
    trial = saved["trials"][0]
    mm = load_dataset(ds).mm_per_tablet_px
    assert trial["mean_px"] == pytest.approx(3.0) and trial["max_px"] == pytest.approx(5.0)
    assert trial["mean_mm"] == pytest.approx(3.0 * mm) and trial["max_mm"] == pytest.approx(5 * mm)
    assert [t["pointer_type"] for t in trial["touches"]] == ["pen", "pen"]
    assert doc["summary"][0]["average"]["mean_px"] == pytest.approx(3.0)
    # Targets said to be the dataset's must be the dataset's.
    status, _ = request(url + "api/evaluation", {**body, "run_id": "t-2", "targets": "dataset"})
    assert status == 409


def test_malformed_evaluation_posts_leave_the_trials_file_byte_identical(served):
    url, ds = served
    touch = {"m": 0, "target_px": [10.0, 20.0], "touch_px": [13.0, 24.0], "pointer_type": "pen"}
    good = {"run_id": "t-1", "label": "stage 2", "targets": "grid", "touches": [touch]}
    assert request(url + "api/evaluation", good)[0] == 200
    trials = ds.parent / "rig.trials.json"
    before = trials.read_bytes()
    bad = [
        (400, b"{not json"),
        (400, {**good, "run_id": "t-2", "extra": 1}),
        (400, {**good, "run_id": "t-2", "label": ""}),
        (400, {**good, "run_id": "t-2", "label": "x" * 201}),
        (400, {**good, "run_id": "t-2", "targets": "elsewhere"}),
        (400, {**good, "run_id": "t-2", "touches": []}),
        (400, {**good, "run_id": "t-2", "touches": [{**touch, "m": 1}]}),
        (400, {**good, "run_id": "t-2", "touches": [{**touch, "touch_px": [1e9, 0.0]}]}),
        (400, {**good, "run_id": "t-2", "touches": [{**touch, "pointer_type": None}]}),
        (400, {**good, "run_id": "t-2", "touches": [{**touch, "target_px": [1.0, None]}]}),
        (409, {**good, "run_id": "t-2", "targets": "file"}),  # no targets file was given
        (413, {**good, "run_id": "t-2", "touches": [touch] * 1001}),
    ]
    for status, body in bad:
        got, doc = request(url + "api/evaluation", body)
        assert got == status, (body, doc)
        assert doc["error"]
    assert trials.read_bytes() == before
    assert sorted(p.name for p in ds.parent.iterdir()) == ["rig.toml", "rig.trials.json"]


def test_a_short_body_cannot_hold_a_thread(tmp_path):
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    before = ds.read_bytes()
    server = start(ds, request_timeout_s=0.5)
    try:
        port = server.server_address[1]
        with socket.create_connection(("127.0.0.1", port), timeout=10) as raw:
            raw.sendall(b"POST /api/calibration HTTP/1.1\r\nHost: x\r\n"
                        b"Content-Type: application/json\r\nContent-Length: 100\r\n\r\n"
                        b'{"run_id":')  # fmt: skip
            t0 = time.monotonic()
            answer = b""
            while chunk := raw.recv(65536):  # until the server closes the connection
                answer += chunk
            waited = time.monotonic() - t0
        assert answer.startswith(b"HTTP/1.0 408") or answer.startswith(b"HTTP/1.1 408"), answer
        assert b"Content-Length" in answer and 0.4 < waited < 5
        with socket.create_connection(("127.0.0.1", port), timeout=10) as idle:
            t0 = time.monotonic()
            assert idle.recv(100) == b""  # a connection that says nothing is closed too
            assert time.monotonic() - t0 < 5
        assert request(server.url + "api/session")[0] == 200  # and the server still serves
    finally:
        stop(server)
    assert ds.read_bytes() == before


def test_bind_failures_name_the_option_to_change(tmp_path, monkeypatch):
    with pytest.raises(Exception, match=r"^--host: '192\.0\.2\.1' is not an address of this"):
        make_server(PAPER, host="192.0.2.1", port=0, trials_path=tmp_path / "t.json")
    for number, option, text in [
        (errno.EACCES, "--port", "no permission to listen on 127.0.0.1:80"),
        (errno.EADDRINUSE, "--port", "127.0.0.1:80 is in use"),
        (errno.EADDRNOTAVAIL, "--host", "not an address of this PC"),
    ]:

        def refuse(*args, number=number, **kwargs):
            raise OSError(number, os.strerror(number))

        monkeypatch.setattr(server_mod.TabletServer, "__init__", refuse)
        with pytest.raises(Exception, match=rf"^{option}: .*{text}") as e:
            make_server(PAPER, port=80, trials_path=tmp_path / "t.json")
        assert "\n" not in str(e.value)

    def unknown(*args, **kwargs):
        raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")

    monkeypatch.setattr(server_mod.TabletServer, "__init__", unknown)
    with pytest.raises(Exception, match=r"^--host: cannot use 'tablet-pc\.lan'"):
        make_server(PAPER, host="tablet-pc.lan", port=80, trials_path=tmp_path / "t.json")
    assert not (tmp_path / "t.json").exists()


def test_the_page_url_for_every_address_is_one_a_tablet_can_open(tmp_path, monkeypatch, capsys):
    assert server_mod.page_urls("0.0.0.0", 8765, ["192.168.1.20", "10.0.0.7"]) == [
        "http://192.168.1.20:8765/", "http://10.0.0.7:8765/",
    ]  # fmt: skip
    assert server_mod.page_urls("127.0.0.1", 8765) == ["http://127.0.0.1:8765/"]
    assert server_mod.page_urls("::", 80, ["fe80::1"]) == ["http://[fe80::1]:80/"]
    found = server_mod.lan_addresses()  # sends nothing; whatever this machine has
    assert all(socket.inet_aton(a) and not a.startswith("127.") for a in found)

    def interrupted(self, *args):
        raise KeyboardInterrupt

    monkeypatch.setattr(server_mod.TabletServer, "serve_forever", interrupted)
    trials = tmp_path / "t.json"
    monkeypatch.setattr(server_mod, "lan_addresses", lambda: ["192.168.1.20"])
    assert serve(PAPER, host="0.0.0.0", port=0, quiet=True, trials_path=trials) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("tablet page: http://192.168.1.20:") and "0.0.0.0" not in lines[0]
    assert "every address of this PC (0.0.0.0)" in lines[1] and "firewall" in lines[1]
    monkeypatch.setattr(server_mod, "lan_addresses", lambda: [])
    assert serve(PAPER, host="0.0.0.0", port=0, quiet=True, trials_path=trials) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "http://THIS-PC:" in first and "no LAN address found" in first


def test_the_trials_summary_gives_max_in_px_and_mm():
    doc = {"trials": [
        {"trial": 1, "label": "stage 2", "mean_px": 3.0, "max_px": 5.0, "mean_mm": 0.57,
         "max_mm": 0.95},
        {"trial": 2, "label": "stage 2", "mean_px": 2.0, "max_px": 4.0, "mean_mm": 0.38,
         "max_mm": 0.76},
    ]}  # fmt: skip
    lines = format_summary(doc).splitlines()
    assert lines[-2].split() == ["max", "in", "px", "5.00", "4.00", "4.50"]
    assert lines[-1].split() == ["max", "in", "mm", "0.95", "0.76", "0.85"]


@pytest.mark.parametrize("key", ["tablet", "trials"])
def test_a_trials_file_without_a_table_names_it_missing(tmp_path, key):
    from handeye_jax.errors import InputError
    from handeye_jax.tablet.trials import load_trials, new_trials

    doc = new_trials(267.0, 2.0)
    del doc[key]
    path = tmp_path / "t.trials.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError) as e:
        load_trials(path, 267.0, 2.0)
    assert str(e.value) == f"{path}: {key}: missing"


def test_grid_endpoint_and_its_errors(served):
    url, _ = served
    status, doc = request(url + "api/grid?cols=3&rows=3&left=400&top=150&right=1040&bottom=550")
    assert status == 200
    np.testing.assert_array_equal(doc["tablet_px"], load_dataset(PAPER).tablet_px)
    for query, field in [
        ("cols=0&rows=3&left=0&top=0&right=9&bottom=9", "cols"),
        ("cols=2&rows=2&left=9&top=0&right=1&bottom=9", "right"),
        ("cols=2&rows=2&left=nan&top=0&right=1&bottom=9", "left"),
        ("cols=2&rows=2&left=0&top=0&right=1", "bottom"),
    ]:
        status, doc = request(url + "api/grid?" + query)
        assert status == 400 and doc["field"] == field


def test_targets_file(tmp_path):
    f = tmp_path / "held_out.json"
    f.write_text(json.dumps({"tablet_px": [[500, 250], [900.5, 450]]}))
    np.testing.assert_array_equal(load_targets(f), [[500, 250], [900.5, 450]])
    f.write_text(json.dumps({"tablet_px": [[500, 250], [900.5]]}))
    with pytest.raises(Exception, match=r"tablet_px\[1\]"):
        load_targets(f)


def _one_error_line(capsys, *needles):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("handeye-jax: error:"), err
    for n in needles:
        assert n in err[0]


def test_cli_errors_are_one_line(tmp_path, capsys):
    broken = tmp_path / "broken.toml"
    broken.write_text(PAPER.read_text().replace("ppi = 267.0", "ppi = nan"))
    assert main(["tablet", "--dataset", str(broken), "--port", "0"]) == 2
    _one_error_line(capsys, "broken.toml", "tablet.ppi")

    assert main(["tablet", "--port", "0"]) == 2
    _one_error_line(capsys, "--ppi")

    trials = tmp_path / "t.json"
    trials.write_text('{"format": "something else"}')
    assert main(["tablet", "--dataset", str(PAPER), "--trials", str(trials), "--port", "0"]) == 2
    _one_error_line(capsys, "t.json", "format")
    assert trials.read_text() == '{"format": "something else"}'

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["tablet", "--dataset", str(PAPER), "--port", str(port)]) == 2
    _one_error_line(capsys, "--port", str(port), "in use")

    missing = tmp_path / "nope.toml"
    assert main(["tablet", "--dataset", str(missing), "--port", "0"]) == 2
    _one_error_line(capsys, "nope.toml", "cannot read")

    for port, why in (("abc", "not a port number"), ("70000", "0 to 65535"), ("-1", "0 to")):
        with pytest.raises(SystemExit) as e:
            main(["tablet", "--dataset", str(PAPER), "--port", port])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--port" in err[0] and why in err[0], err

    targets = tmp_path / "held_out.json"
    for text, field in (
        ("{not json", "cannot read targets"),
        ('{"tablet_px": [[1, 2], [3]]}', "tablet_px[1]"),
        ('{"tablet_px": [[1, 2], [-3, 4]]}', "tablet_px[1]"),
        ('{"format": "x", "tablet_px": [[1, 2]]}', "format"),
    ):
        targets.write_text(text)
        argv = ["tablet", "--dataset", str(PAPER), "--targets", str(targets), "--port", "0"]
        assert main(argv) == 2
        _one_error_line(capsys, "held_out.json", field)
    assert main(["tablet", "--dataset", str(PAPER), "--targets", str(missing), "--port", "0"]) == 2
    _one_error_line(capsys, "nope.toml")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.toml", "held_out.json", "t.json"]


def paper_result(path, dataset_name="paper2023"):
    """A result file holding the paper's printed seed-1 HTM values (Tables 7 and 10)."""
    from test_paper import TABLE7

    from handeye_jax.result import CalibrationResult, StageResult, rig_to_dict

    table10 = dict(X1=-0.10, Y1=0.0, theta1=0.03, Sx1=1.00, Sy1=1.02,
                   X2=0.06, Y2=-0.11, theta2=0.0, Sx2=1.02, Sy2=0.99)  # fmt: skip

    def stage(F, f1, f2, params):
        return StageResult(F=F, f1=f1, f2=f2, params=params, residuals_mm=[], de={}, polish={})

    CalibrationResult(
        model="htm", seed=1, settings={}, dataset=dataset_name,
        rig=rig_to_dict(load_dataset(PAPER).rig()),
        stage1=stage(1.68, 0.64, 1.04, TABLE7), stage2=stage(1.00, 0.19, 0.82, table10),
        centre_index=4, centres_mm=[[0.0, 0.0], [0.0, 0.0]], timings_s={}, sign_twin={},
        warnings=[],
    ).save(path)  # fmt: skip
    return path


def test_the_result_being_evaluated_is_named_and_checked(tmp_path):
    trials = tmp_path / "trials.json"
    same = make_server(
        PAPER, port=0, quiet=True, result=paper_result(tmp_path / "r.json"), trials_path=trials
    )
    other = make_server(
        PAPER, port=0, quiet=True, result=paper_result(tmp_path / "o.json", "another rig")
    )
    try:
        info = same.app.session()["result"]
        assert info["model"] == "htm" and info["seed"] == 1 and "note" not in info
        assert "another rig" in other.app.session()["result"]["note"]
        touch = {"m": 0, "target_px": [10, 20], "touch_px": [11, 20], "pointer_type": "touch"}
        body = {"run_id": "r", "label": "stage 2", "targets": "grid", "touches": [touch]}
        assert same.app.post_evaluation(body)["mean_px"] == 1.0
        saved = json.loads(trials.read_text())["trials"][0]
        assert saved["result"]["path"].endswith("r.json") and saved["result"]["model"] == "htm"
    finally:
        same.server_close()
        other.server_close()


def test_the_command_serves_until_interrupted(tmp_path):
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    cmd = [sys.executable, "-m", "handeye_jax.cli", "tablet", "--dataset", str(ds), "--port", "0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        first = proc.stdout.readline()
        assert first.startswith("tablet page: http://127.0.0.1:"), first
        url = first.split()[2]
        status, doc = request(url + "api/session")
        assert status == 200 and doc["dataset"]["name"] == "paper2023"
        assert doc["tablet"]["mm_per_px"] == pytest.approx(25.4 / 267 * 2)
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0 and "stopped" in out


# -- files the posts write: checked before serving, a failed save named and kept for retry --


@pytest.fixture
def no_bind(monkeypatch):
    """Binding the server fails the test: every check must come before it."""

    def bind(*args, **kwargs):
        raise AssertionError("the server was bound before its output files were checked")

    monkeypatch.setattr(server_mod.TabletServer, "__init__", bind)


def _listing(folder):
    return {p.name: p.read_bytes() if p.is_file() else None for p in Path(folder).iterdir()}


def test_an_unwritable_default_trials_file_is_refused_before_serving(
    tmp_path, monkeypatch, capsys, no_bind
):
    # Without --dataset the default is tablet-trials.json in the working folder: here /sys.
    monkeypatch.chdir("/sys")
    assert main(["tablet", "--ppi", "267", "--scale", "2", "--port", "0"]) == 2
    _one_error_line(capsys, "tablet-trials.json: --trials: cannot write", "default trials file")
    assert not Path("/sys/tablet-trials.json").exists()
    monkeypatch.chdir(tmp_path)
    # With --dataset it is DATASET_STEM.trials.json beside the dataset: here a folder.
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    (tmp_path / "rig.trials.json").mkdir()
    before = _listing(tmp_path)
    assert main(["tablet", "--dataset", str(ds), "--port", "0"]) == 2
    _one_error_line(capsys, f"{tmp_path / 'rig.trials.json'}: --trials: cannot write: is a "
                    "folder", "the default trials file", "choose one with --trials")  # fmt: skip
    assert _listing(tmp_path) == before  # no probe or temporary file left
    # The library checks a given trials file too (the command line checks it first).
    with pytest.raises(Exception, match=r"afile.t\.json: --trials: cannot write") as e:
        (tmp_path / "afile").write_text("a file, not a folder")
        make_server(ds, port=0, trials_path=tmp_path / "afile" / "t.json")
    assert "default trials file" not in str(e.value)


def test_a_dataset_whose_folder_cannot_be_written_is_refused_before_serving(
    tmp_path, monkeypatch, capsys, no_bind
):
    from handeye_jax import _atomic

    folder = tmp_path / "rig"
    folder.mkdir()
    ds = folder / "rig.toml"
    shutil.copy(PAPER, ds)
    trials = tmp_path / "t.json"  # writable: only the dataset's folder is not
    argv = ["tablet", "--dataset", str(ds), "--trials", str(trials), "--port", "0"]
    real = _atomic.tempfile.mkstemp

    def denied(*args, dir=None, prefix="", suffix="", **kwargs):
        if dir is not None and Path(dir) == folder:  # as in a folder the user cannot write
            raise PermissionError(13, "Permission denied", f"{dir}/{prefix}x1y2{suffix}")
        return real(*args, dir=dir, prefix=prefix, suffix=suffix, **kwargs)

    monkeypatch.setattr(_atomic.tempfile, "mkstemp", denied)
    before = _listing(folder)
    assert main(argv) == 2
    _one_error_line(capsys, f"{ds}: --dataset: cannot write in folder", "Permission denied",
                    "keeps the previous file as rig.toml.bak")  # fmt: skip
    assert _listing(folder) == before and not trials.exists()
    monkeypatch.setattr(_atomic.tempfile, "mkstemp", real)
    # A folder where the backup goes: calibration could write the dataset but not keep it.
    (folder / "rig.toml.bak").mkdir()
    assert main(argv) == 2
    _one_error_line(capsys, "rig.toml.bak: --dataset: cannot write: is a folder")
    assert list((folder / "rig.toml.bak").iterdir()) == [] and ds.read_bytes() == PAPER.read_bytes()
    (folder / "rig.toml.bak").rmdir()
    monkeypatch.undo()  # the same files in a writable folder: the server starts
    stop(start(ds, trials_path=trials))


def _failing_replace(monkeypatch, target):
    """``os.replace`` onto ``target`` fails as on a full disk (its message naming the temp)."""
    real = os.replace

    def full(src, dst, *args, **kwargs):
        if Path(dst) == target:
            raise OSError(errno.ENOSPC, "No space left on device", str(src), str(dst))
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", full)


def _server_error(status, doc, path):
    """A 500 (the page keeps the run and retries) naming ``path`` and the reason, one line."""
    assert status == 500 and doc["status"] == 500, doc
    error = doc["error"]
    assert error.startswith(f"{path}: ") and error.endswith(": No space left on device"), error
    assert "\n" not in error and ".tmp" not in error and "Errno" not in error, error


def test_a_failed_trials_save_is_a_500_naming_the_file_and_the_post_can_be_resent(
    served, monkeypatch
):
    url, ds = served
    trials = ds.parent / "rig.trials.json"
    touch = {"m": 0, "target_px": [10.0, 20.0], "touch_px": [13.0, 24.0], "pointer_type": "pen"}
    body = {"run_id": "t-1", "label": "stage 2", "targets": "grid", "touches": [touch]}
    _failing_replace(monkeypatch, trials)
    status, doc = request(url + "api/evaluation", body)
    _server_error(status, doc, trials)
    assert doc["error"] == f"{trials}: cannot write: No space left on device"
    assert sorted(p.name for p in ds.parent.iterdir()) == ["rig.toml"]  # no temp, no trials
    monkeypatch.undo()
    status, doc = request(url + "api/evaluation", body)  # the page's retry
    assert status == 200 and doc["trial"] == 1 and doc["mean_px"] == pytest.approx(5.0)
    assert [t["run_id"] for t in json.loads(trials.read_text())["trials"]] == ["t-1"]


def test_a_failed_dataset_save_is_a_500_naming_the_file_and_the_post_can_be_resent(
    served, monkeypatch
):
    url, ds = served
    before = ds.read_bytes()
    tablet_px = load_dataset(ds).tablet_px.tolist()
    errors = [[1.0, -2.0]] * 9
    backup = ds.parent / "rig.toml.bak"
    for target in (backup, ds):  # the backup fails, or the dataset after the backup
        _failing_replace(monkeypatch, target)
        status, doc = request(url + "api/calibration", calibration_body(tablet_px, errors))
        _server_error(status, doc, target)
        assert ds.read_bytes() == before
        assert {p.name for p in ds.parent.iterdir()} <= {"rig.toml", "rig.toml.bak"}
        monkeypatch.undo()
    status, doc = request(url + "api/calibration", calibration_body(tablet_px, errors))
    assert status == 200 and doc["written"] is True
    np.testing.assert_array_equal(load_dataset(ds).touch_error_px, errors)
    assert backup.read_bytes() == before
