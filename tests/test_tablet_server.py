"""The tablet server without a browser: only the operator gets in, strict bounded posts,
files never corrupted, the first and the last 50 versions of the dataset kept, one-line
errors; no stranger can stall it, flood its log or write to its terminal.

Most tests use a server in this process (over a copy of the paper's dataset); the ones on
who may get in (the secret, Host, Origin) and on what the listening socket takes run against
one real server process, started as the operator starts it.
"""

import datetime as dt
import errno
import http.client
import importlib.util
import json
import os
import re
import select
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import jax
import numpy as np
import pytest
from test_dataset import commented_paper_text, comments_of

from handeye_jax import InputError, load_dataset, save_dataset
from handeye_jax.cli import main
from handeye_jax.tablet import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    MAX_BODY_BYTES,
    MAX_TOUCHES,
    MAX_TRIALS,
    EvaluationFiles,
    Listen,
    apply_touch_errors,
    grid_targets,
    load_targets,
    make_server,
    parse_calibration,
    serve,
    versioned_backup_path,
)
from handeye_jax.tablet import _server as server_mod
from handeye_jax.tablet._app import SAVE_BURST
from handeye_jax.tablet._calibration import MAX_BACKUPS, prune_backups
from handeye_jax.tablet._trials import format_summary, new_trials

PAPER = Path(__file__).resolve().parents[1] / "data" / "paper2023.toml"
REPO = Path(__file__).resolve().parents[1]
BENCH = REPO / "benchmarks"
# The in-process servers' secret (Listen's token=, as a script would give it).
TOKEN = "test-secret-0123456789-abcdefghijklmnopqrstuvwxyz"
BACKUP_NAME = re.compile(r"^rig\.toml\.\d{4}-\d\d-\d\dT\d\d-\d\d-\d\d\.\d{3}Z(-\d+)?\.bak$")


def backups(folder):
    """The dataset's versioned backups in ``folder``, oldest first."""
    found = sorted(p for p in Path(folder).iterdir() if p.name.endswith(".bak"))
    assert all(BACKUP_NAME.match(p.name) for p in found), found
    return found


def start(ds, request_timeout_s=server_mod.DEFAULT_REQUEST_TIMEOUT_S, **files):
    """A running server over ``ds`` on a free port; ``files`` as for :class:`EvaluationFiles`."""
    listen = Listen(port=0, token=TOKEN, request_timeout_s=request_timeout_s)
    server = make_server(ds, listen=listen, files=EvaluationFiles(**files), quiet=True)
    threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True).start()
    return server


def stop(server):
    server.shutdown()
    server.server_close()


def _trials(path):
    """Evaluation mode's files with only the trials file given."""
    return EvaluationFiles(trials=path)


@pytest.fixture
def served(tmp_path):
    """A server on a free port over a copy of the paper's dataset; yields (url, dataset path)."""
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    server = start(ds)
    yield server.url, ds
    stop(server)


def request(url, body=None, headers=None, method=None, token=TOKEN):
    """(status, JSON answer) of a request with the secret ``token`` (none if ``None``);
    ``body`` is bytes or a JSON-able object."""
    data = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
    h = {"Content-Type": "application/json"} if data is not None else {}
    if token is not None:
        h["X-Handeye-Token"] = token
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
    [backup] = backups(ds.parent)
    assert backup.read_bytes() == before and doc["backup"] == backup.name
    # A resend (the answer was lost) writes nothing and makes no backup.
    status, doc = request(url + "api/calibration", calibration_body(old.tablet_px.tolist(), errors))
    assert status == 200 and doc["written"] is False and doc["backup"] is None
    assert backups(ds.parent) == [backup]


def test_every_saved_version_of_the_dataset_is_kept(served):
    """Issue 16: one DATASET.bak was overwritten by the next post, losing the original."""
    url, ds = served
    tablet_px = load_dataset(ds).tablet_px.tolist()
    versions = [ds.read_bytes()]
    for k in range(3):
        errors = np.full((9, 2), float(k + 1))
        status, doc = request(url + "api/calibration", calibration_body(tablet_px, errors, f"r{k}"))
        assert status == 200 and doc["written"] is True
        versions.append(ds.read_bytes())
    kept = backups(ds.parent)
    assert [p.read_bytes() for p in kept] == versions[:-1]  # the original first, none lost
    assert doc["backup"] == kept[-1].name and ds.read_bytes() == versions[-1]
    np.testing.assert_array_equal(load_dataset(kept[1]).touch_error_px, np.full((9, 2), 1.0))


def test_a_backup_name_is_never_one_that_exists(tmp_path):
    ds = tmp_path / "rig.toml"
    when = dt.datetime(2026, 12, 2, 7, 37, 28, 123456, tzinfo=dt.UTC)
    first = versioned_backup_path(ds, when)
    assert first.name == "rig.toml.2026-12-02T07-37-28.123Z.bak"
    first.write_text("kept")
    second = versioned_backup_path(ds, when)
    assert second.name == "rig.toml.2026-12-02T07-37-28.123Z-2.bak"
    second.write_text("kept too")
    assert versioned_backup_path(ds, when).name.endswith("123Z-3.bak")
    later = versioned_backup_path(ds, when + dt.timedelta(milliseconds=1))
    assert sorted([first.name, later.name]) == [first.name, later.name]  # names sort by time


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
    [backup] = backups(tmp_path)
    assert backup.read_bytes() == before


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
        (413, {**good, "run_id": "t-2", "touches": [touch] * (MAX_TOUCHES + 1)}),
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
            raw.sendall(f"POST /api/calibration HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                        f"X-Handeye-Token: {TOKEN}\r\nContent-Type: application/json\r\n"
                        'Content-Length: 100\r\n\r\n{"run_id":'.encode())  # fmt: skip
            t0 = time.monotonic()
            answer = b""
            while chunk := raw.recv(65536):  # until the server closes the connection
                answer += chunk
            waited = time.monotonic() - t0
        assert answer.startswith(b"HTTP/1.1 408"), answer
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
        make_server(PAPER, listen=Listen("192.0.2.1", 0), files=_trials(tmp_path / "t.json"))
    for number, option, text in [
        (errno.EACCES, "--port", "no permission to listen on 127.0.0.1:80"),
        (errno.EADDRINUSE, "--port", "127.0.0.1:80 is in use"),
        (errno.EADDRNOTAVAIL, "--host", "not an address of this PC"),
    ]:

        def refuse(*args, number=number, **kwargs):
            raise OSError(number, os.strerror(number))

        monkeypatch.setattr(server_mod.TabletServer, "__init__", refuse)
        with pytest.raises(Exception, match=rf"^{option}: .*{text}") as e:
            make_server(PAPER, listen=Listen(port=80), files=_trials(tmp_path / "t.json"))
        assert "\n" not in str(e.value)

    def unknown(*args, **kwargs):
        raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")

    monkeypatch.setattr(server_mod.TabletServer, "__init__", unknown)
    with pytest.raises(Exception, match=r"^--host: cannot use 'tablet-pc\.lan'"):
        listen = Listen("tablet-pc.lan", 80)
        make_server(PAPER, listen=listen, files=_trials(tmp_path / "t.json"))
    assert not (tmp_path / "t.json").exists()


def qr_decode(lines):
    """The text of a QR code printed in half blocks (``guard.qr_text``), read by OpenCV."""
    import cv2

    dark = {"█": (False, False), "▀": (False, True), "▄": (True, False), " ": (True, True)}
    rows = []
    for line in lines:
        cells = [dark[c] for c in re.sub(r"\x1b\[[0-9;]*m", "", line)]
        rows += [[top for top, _ in cells], [bottom for _, bottom in cells]]
    img = np.pad(np.where(np.array(rows), 0, 255).astype(np.uint8), 8, constant_values=255)
    img = cv2.resize(img, None, fx=8, fy=8, interpolation=cv2.INTER_NEAREST)
    # OpenCV's plain detector misreads about 1.5 % of these codes (3 of 200 random secrets,
    # measured); its ArUco-based one read all 200.
    return cv2.QRCodeDetectorAruco().detectAndDecode(img)[0]


def test_the_page_url_for_every_address_carries_the_secret_and_a_qr_code(
    tmp_path, monkeypatch, capsys
):
    assert server_mod.page_urls("0.0.0.0", 8765, ["192.168.1.20", "10.0.0.7"], "s3") == [
        "http://192.168.1.20:8765/?token=s3", "http://10.0.0.7:8765/?token=s3",
    ]  # fmt: skip
    assert server_mod.page_urls("127.0.0.1", 8765) == ["http://127.0.0.1:8765/"]
    assert server_mod.page_urls("::", 80, ["fe80::1"]) == ["http://[fe80::1]:80/"]
    found = server_mod.lan_addresses()  # sends nothing; whatever this machine has
    assert all(socket.inet_aton(a) and not a.startswith("127.") for a in found)

    def interrupted(self, *args):
        raise KeyboardInterrupt

    monkeypatch.setattr(server_mod.TabletServer, "serve_forever", interrupted)
    trials = tmp_path / "t.json"
    everywhere = Listen("0.0.0.0", 0)
    monkeypatch.setattr(server_mod, "lan_addresses", lambda: ["192.168.1.20", "10.0.0.7"])
    assert serve(PAPER, listen=everywhere, quiet=True, files=_trials(trials)) == 0
    lines = capsys.readouterr().out.splitlines()
    url = lines[0].split()[2]
    assert re.fullmatch(r"http://192\.168\.1\.20:\d+/\?token=[\w-]{43}", url), lines[0]
    qr = [line for line in lines if line and set(line) <= set("█▀▄ ")]
    assert len(qr) > 10 and qr_decode(qr) == url  # the QR code is the first URL, exactly
    secret = url.split("token=")[1]
    others = [line for line in lines if "10.0.0.7" in line or "127.0.0.1" in line]
    assert len(others) == 2 and all(f"?token={secret}" in line for line in others)
    wildcard = [line for line in lines if "every address of this PC (0.0.0.0)" in line]
    assert len(wildcard) == 1 and "firewall" in wildcard[0]
    # Each start makes a new secret.
    assert serve(PAPER, listen=everywhere, quiet=True, files=_trials(trials)) == 0
    assert capsys.readouterr().out.split("token=")[1][:43] != secret
    monkeypatch.setattr(server_mod, "lan_addresses", lambda: [])
    assert serve(PAPER, listen=everywhere, quiet=True, files=_trials(trials)) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "http://THIS-PC:" in first and "no LAN address found" in first and "token=" in first
    # Only this PC can open a server on 127.0.0.1: its URL, without a QR code to scan.
    assert serve(PAPER, listen=Listen(port=0), quiet=True, files=_trials(trials)) == 0
    out = capsys.readouterr().out
    assert out.startswith("tablet page: http://127.0.0.1:") and "█" not in out


def test_the_secret_is_random_and_a_given_one_must_be_as_strong(tmp_path):
    trials = tmp_path / "t.json"
    servers = [
        make_server(PAPER, listen=Listen(port=0), quiet=True, files=_trials(trials))
        for _ in range(2)
    ]
    try:
        tokens = [s.token for s in servers]
        assert tokens[0] != tokens[1] and all(re.fullmatch(r"[\w-]{43}", t) for t in tokens)
        assert servers[0].secret_url == f"{servers[0].url}?token={tokens[0]}"
    finally:
        for s in servers:
            s.server_close()
    for weak in ("", "short", "x" * 31, "a b" * 20, "é" * 40, "x" * 40 + "\n"):
        with pytest.raises(InputError, match=r"^token: must be at least 32 characters"):
            Listen(port=0, token=weak)


def test_listen_defaults_to_this_pc_only_with_a_new_secret_and_refuses_a_bad_field():
    listen = Listen()
    assert (listen.host, listen.port, listen.token) == (DEFAULT_HOST, DEFAULT_PORT, None)
    assert DEFAULT_HOST == "127.0.0.1" and listen.request_timeout_s == 10.0
    assert TOKEN not in repr(Listen(token=TOKEN))  # the secret stays out of logs
    for bad, field in (({"port": 65536}, "port"), ({"port": -1}, "port"),
                       ({"request_timeout_s": 0.0}, "request_timeout_s"),
                       ({"request_timeout_s": float("nan")}, "request_timeout_s"),
                       ({"token": "short"}, "token")):  # fmt: skip
        with pytest.raises(InputError, match=rf"^{field}: must"):
            Listen(**bad)
    assert EvaluationFiles() == EvaluationFiles(None, None, None)


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
    from handeye_jax import InputError
    from handeye_jax.tablet._trials import load_trials, new_trials

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

    from handeye_jax import (
        AffinePair,
        CalibrationResult,
        HTMModel,
        Settings,
        StageResult,
        save_result,
    )

    table10 = dict(X1=-0.10, Y1=0.0, theta1=0.03, Sx1=1.00, Sy1=1.02,
                   X2=0.06, Y2=-0.11, theta2=0.0, Sx2=1.02, Sy2=0.99)  # fmt: skip

    def stage(F, f1, f2, params):
        return StageResult(F=F, f1=f1, f2=f2, params=params)

    with jax.enable_x64(True):
        result = CalibrationResult(
            model=HTMModel.from_dict(TABLE7), correction=AffinePair.from_dict(table10),
            rig=load_dataset(PAPER).rig(), centres_mm=[[0.0, 0.0], [0.0, 0.0]], centre_index=4,
            stage1=stage(1.68, 0.64, 1.04, TABLE7), stage2=stage(1.00, 0.19, 0.82, table10),
            settings=Settings(seed=1), dataset_name=dataset_name,
        )  # fmt: skip
    save_result(result, path)
    return path


def test_the_result_being_evaluated_is_named_and_checked(tmp_path):
    trials = tmp_path / "trials.json"
    same = make_server(
        PAPER, listen=Listen(port=0), quiet=True,
        files=EvaluationFiles(result=paper_result(tmp_path / "r.json"), trials=trials),
    )  # fmt: skip
    other = make_server(
        PAPER, listen=Listen(port=0), quiet=True,
        files=EvaluationFiles(result=paper_result(tmp_path / "o.json", "another rig")),
    )  # fmt: skip
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
        make_server(ds, listen=Listen(port=0), files=_trials(tmp_path / "afile" / "t.json"))
    assert "default trials file" not in str(e.value)


def test_a_dataset_whose_folder_cannot_be_written_is_refused_before_serving(
    tmp_path, monkeypatch, capsys, no_bind
):
    import handeye_jax._core._atomic as _atomic

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
                    "keeps previous versions as rig.toml.<UTC time>.bak")  # fmt: skip
    assert _listing(folder) == before and not trials.exists()
    monkeypatch.undo()  # the same files in a writable folder: the server starts
    stop(start(ds, trials=trials))


def _failing_replace(monkeypatch, fails):
    """``os.replace`` onto a path for which ``fails(path)`` fails as on a full disk (its
    message naming the temporary file)."""
    real = os.replace

    def full(src, dst, *args, **kwargs):
        if fails(Path(dst)):
            raise OSError(errno.ENOSPC, "No space left on device", str(src), str(dst))
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", full)


def _server_error(status, doc, path):
    """A 500 (the page keeps the run and retries) naming ``path``'s file (by its name: no
    folder of the PC goes out) and the reason, one line."""
    assert status == 500 and doc["status"] == 500, doc
    error = doc["error"]
    assert error.startswith(f"{path.name}: ") and error.endswith(": No space left on device")
    assert "\n" not in error and ".tmp" not in error and "Errno" not in error, error
    assert str(path.parent) not in error, error


def test_a_failed_trials_save_is_a_500_naming_the_file_and_the_post_can_be_resent(
    served, monkeypatch
):
    url, ds = served
    trials = ds.parent / "rig.trials.json"
    touch = {"m": 0, "target_px": [10.0, 20.0], "touch_px": [13.0, 24.0], "pointer_type": "pen"}
    body = {"run_id": "t-1", "label": "stage 2", "targets": "grid", "touches": [touch]}
    _failing_replace(monkeypatch, lambda p: p == trials)
    status, doc = request(url + "api/evaluation", body)
    _server_error(status, doc, trials)
    assert doc["error"] == "rig.trials.json: cannot write: No space left on device"
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
    for fails, named in (  # the backup fails, or the dataset after the backup
        (lambda p: bool(BACKUP_NAME.match(p.name)), BACKUP_NAME),
        (lambda p: p == ds, re.compile(r"^rig\.toml$")),
    ):
        _failing_replace(monkeypatch, fails)
        status, doc = request(url + "api/calibration", calibration_body(tablet_px, errors))
        name = doc["error"].split(": ")[0]
        assert named.match(name), doc
        _server_error(status, doc, ds.parent / name)
        assert ds.read_bytes() == before
        assert sorted(p.name for p in ds.parent.iterdir()) == ["rig.toml"]  # no backup, no temp
        monkeypatch.undo()
    status, doc = request(url + "api/calibration", calibration_body(tablet_px, errors))
    assert status == 200 and doc["written"] is True
    np.testing.assert_array_equal(load_dataset(ds).touch_error_px, errors)
    [backup] = backups(ds.parent)
    assert backup.read_bytes() == before


# -- bounds on what posts may hold ------------------------------------------------------------


def test_a_full_trials_file_refuses_another_trial(tmp_path):
    """Issue 16: posts grew the trials file without limit (40 posts: 11 MB)."""
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    doc = new_trials(267.0, 2.0)
    record = {"trial": 1, "label": "stage 2", "mean_px": 1.0, "max_px": 2.0, "mean_mm": 0.19,
              "max_mm": 0.38}  # fmt: skip
    doc["trials"] = [{**record, "trial": i + 1, "run_id": f"old-{i}"} for i in range(MAX_TRIALS)]
    trials = tmp_path / "rig.trials.json"
    trials.write_text(json.dumps(doc))
    before = trials.read_bytes()
    server = start(ds)
    try:
        touch = {"m": 0, "target_px": [10.0, 20.0], "touch_px": [13.0, 24.0], "pointer_type": "pen"}
        body = {"run_id": "new", "label": "stage 2", "targets": "grid", "touches": [touch]}
        status, answer = request(server.url + "api/evaluation", body)
        assert status == 409 and answer["field"] == "trials", answer
        assert f"holds {MAX_TRIALS} trials, the limit" in answer["error"]
        assert "--trials" in answer["error"]
        # A resend of a saved trial is still answered (nothing to add).
        status, answer = request(server.url + "api/evaluation", {**body, "run_id": "old-3"})
        assert status == 200 and answer["trial"] == 4
    finally:
        stop(server)
    assert trials.read_bytes() == before


def test_runs_and_grids_are_bounded(served, tmp_path):
    url, _ = served
    status, doc = request(url + "api/session")
    limits = {"max_body_bytes": MAX_BODY_BYTES, "max_touches": MAX_TOUCHES,
              "max_trials": MAX_TRIALS, "pointer_types": ["pen", "touch", "mouse"]}  # fmt: skip
    assert doc["limits"] == limits
    status, doc = request(url + "api/grid?cols=11&rows=10&left=0&top=0&right=900&bottom=900")
    assert status == 400 and doc["field"] == "rows" and f"at most {MAX_TOUCHES}" in doc["error"]
    assert request(url + "api/grid?cols=10&rows=10&left=0&top=0&right=900&bottom=900")[0] == 200
    # A dataset with more landmarks than a run may touch is refused before serving.
    big = tmp_path / "big.toml"
    text = PAPER.read_text()
    first = text.index("[[landmarks]]")
    block = text[first : text.index("[[landmarks]]", first + 1)]
    extra = "".join(
        block.replace("tablet_px = [400.0, 150.0]", f"tablet_px = [{10 + i}.0, 20.0]")
        for i in range(MAX_TOUCHES)
    )
    big.write_text(text + "\n" + extra)
    with pytest.raises(InputError, match=rf"big\.toml: landmarks: {MAX_TOUCHES + 9} landmarks"):
        make_server(big, listen=Listen(port=0), files=_trials(tmp_path / "t.json"))


def test_an_oversized_trials_file_is_refused_before_serving(tmp_path):
    from handeye_jax.tablet import _trials as trials_mod

    path = tmp_path / "t.json"
    path.write_text(" " * (trials_mod.MAX_FILE_BYTES + 1))
    message = r"t\.json: cannot read trials: is [\d,]+ bytes, larger than 16 MiB"
    with pytest.raises(InputError, match=message):
        make_server(PAPER, listen=Listen(port=0), files=_trials(path))


def test_the_session_names_files_not_paths(tmp_path):
    """Issue 16: /api/session gave the absolute paths of the dataset, backup and trials."""
    folder = tmp_path / "lab" / "rig"
    folder.mkdir(parents=True)
    ds = folder / "rig.toml"
    shutil.copy(PAPER, ds)
    targets = folder / "held_out.json"
    targets.write_text(json.dumps({"tablet_px": [[500, 250]]}))
    result = paper_result(folder / "r.json")
    server = start(ds, targets=targets, result=result)
    try:
        status, doc = request(server.url + "api/session")
    finally:
        stop(server)
    assert status == 200
    text = json.dumps(doc)
    assert str(tmp_path) not in text and "lab" not in text and "/" not in text.replace("\\/", "")
    assert doc["dataset"]["file"] == "rig.toml" and doc["trials"]["file"] == "rig.trials.json"
    assert doc["targets_file"]["file"] == "held_out.json" and doc["result"]["file"] == "r.json"


# -- the real server process: who may get in ----------------------------------------------------


class ServerProcess:
    """``handeye-jax tablet`` as the operator runs it, its URL and secret read from its output,
    its log (standard error) collected as it comes."""

    def __init__(self, folder, *extra):
        self.dataset = Path(folder) / "rig.toml"
        shutil.copy(PAPER, self.dataset)
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        cmd = [sys.executable, "-m", "handeye_jax.cli", "tablet", "--dataset",
               str(self.dataset), "--port", "0", *extra]  # fmt: skip
        self.proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
        )
        first = self.proc.stdout.readline()
        match = re.match(r"tablet page: (http://127\.0\.0\.1:(\d+)/)\?token=([\w-]+)", first)
        assert match, first
        self.url, self.port, self.token = match[1], int(match[2]), match[3]
        self.secret_url = f"{self.url}?token={self.token}"
        self.log = []
        threading.Thread(target=self._read_log, daemon=True).start()

    def _read_log(self):
        for line in self.proc.stderr:
            self.log.append(line)

    def wait_log(self, *needles, timeout=10.0):
        """The first log line holding every needle (waits for it)."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            for line in list(self.log):
                if all(n in line for n in needles):
                    return line
            time.sleep(0.02)
        raise AssertionError(f"no log line with {needles}: {self.log[-5:]}")

    def raw(self, method, path, headers=None, body=b"", host=None):
        """(status, headers, body) of one request with exactly these headers."""
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        conn.putheader("Host", f"127.0.0.1:{self.port}" if host is None else host)
        for key, value in (headers or {}).items():
            conn.putheader(key, value)
        if body or method == "POST":
            conn.putheader("Content-Length", str(len(body)))
        conn.endheaders(body or None)
        r = conn.getresponse()
        out = r.status, dict(r.getheaders()), r.read()
        conn.close()
        return out

    def api(self, method, path, doc=None, headers=None, **kwargs):
        """A request with the secret (unless ``headers`` carry another) and a JSON body."""
        h = {"X-Handeye-Token": self.token, "Content-Type": "application/json", **(headers or {})}
        h = {k: v for k, v in h.items() if v is not None}
        body = json.dumps(doc).encode() if doc is not None else b""
        status, headers_, raw = self.raw(method, path, h, body, **kwargs)
        return status, (json.loads(raw) if raw else None)

    def stop(self):
        self.proc.send_signal(signal.SIGINT)
        out, _ = self.proc.communicate(timeout=30)
        return out


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("real"))
    yield server
    out = server.stop()  # Ctrl-C
    assert server.proc.returncode == 0 and "stopped" in out


def test_the_command_serves_until_interrupted(real):
    status, doc = real.api("GET", "/api/session")
    assert status == 200 and doc["dataset"]["name"] == "paper2023"
    assert doc["tablet"]["mm_per_px"] == pytest.approx(25.4 / 267 * 2)


def _touches(tablet_px, errors):
    return calibration_body(tablet_px, errors)["touches"]


def test_without_the_secret_every_api_request_gets_403(real):
    """Issue 16: there was no token; any device on the network could post."""
    before = real.dataset.read_bytes()
    tablet_px = load_dataset(real.dataset).tablet_px.tolist()
    body = calibration_body(tablet_px, [[5.0, 5.0]] * 9)
    wrong = "x" * 43
    cookie = f"handeye-jax-token-{real.port}"
    for headers in (
        {"X-Handeye-Token": None},
        {"X-Handeye-Token": wrong},
        {"X-Handeye-Token": real.token[:-1]},
        {"X-Handeye-Token": None, "Authorization": f"token {wrong}"},
        {"X-Handeye-Token": None, "Cookie": f"{cookie}={wrong}"},
        {"X-Handeye-Token": None, "Cookie": f"handeye-jax-token-1={real.token}"},  # another port's
    ):
        for method, path, doc in (
            ("GET", "/api/session", None),
            ("GET", "/api/grid?cols=3&rows=3&left=400&top=150&right=1040&bottom=550", None),
            ("POST", "/api/calibration", body),
            ("POST", "/api/evaluation", {"run_id": "x"}),
            ("GET", f"/api/session?token={real.token}", None),  # an API URL is not a login
        ):
            status, answer = real.api(method, path, doc, headers)
            assert status == 403 and answer["field"] == "token", (headers, path, answer)
            assert "open the URL the server printed" in answer["error"]
    assert real.dataset.read_bytes() == before
    # With it, by header, by Authorization or by cookie (and other cookies around it):
    for headers in (
        {},
        {"X-Handeye-Token": None, "Authorization": f"token {real.token}"},
        {"X-Handeye-Token": None, "Cookie": f'a="b; c; {cookie}={real.token}; d=e'},
    ):
        status, answer = real.api("GET", "/api/session", None, headers)
        assert status == 200 and answer["dataset"]["name"] == "paper2023", headers


def test_the_first_load_with_the_secret_sets_a_cookie_and_leaves_the_url(real):
    status, headers, body = real.raw("GET", f"/?token={real.token}")
    assert status == 303 and headers["Location"] == "/" and body == b""
    cookie = headers["Set-Cookie"]
    name_value, *attributes = [part.strip() for part in cookie.split(";")]
    assert name_value == f"handeye-jax-token-{real.port}={real.token}"
    assert set(attributes) == {"Path=/", "HttpOnly", "SameSite=Strict"}
    assert headers["Referrer-Policy"] == "no-referrer"  # the secret URL goes nowhere else
    status, headers, page = real.raw("GET", "/", {"Cookie": name_value})
    assert status == 200 and b'<script src="app.js">' in page
    # Without the secret, or with a wrong one, the page says where to get it; no app.
    for path, why in (
        ("/", "does not have the server's secret"),
        (f"/?token={'y' * 43}", "is not this server's (was it restarted?)"),
    ):
        status, headers, page = real.raw("GET", path)
        assert status == 403 and "Set-Cookie" not in headers
        assert b"scan the QR code" in page and why.encode() in page and b"app.js" not in page
    for path in ("/app.js", "/style.css"):
        assert real.raw("GET", path)[0] == 403
    # The log (the operator's terminal) never shows the secret.
    line = real.wait_log("GET /?token=")
    assert "token=[secret]" in line
    assert not any(real.token in line for line in real.log)


def test_a_host_that_is_not_the_servers_is_refused(real):
    """Issue 16: a post with ``Host: attacker.example`` was answered 200 and rewrote
    ``touch_error_px``; a page using DNS rebinding reaches a server on 127.0.0.1 that way."""
    before = real.dataset.read_bytes()
    tablet_px = load_dataset(real.dataset).tablet_px.tolist()
    body = calibration_body(tablet_px, [[5.0, 5.0]] * 9)
    port = real.port
    requests = (("GET", "/api/session", None), ("POST", "/api/calibration", body))
    for host in (f"attacker.example:{port}", "attacker.example", f"127.0.0.1:{port + 1}",
                 f"127.0.0.2:{port}", f"127.0.0.1.attacker.example:{port}", f"[::1]:{port}",
                 f"localhost.:{port}", "", "127.0.0.1:abc"):  # fmt: skip
        for method, path, doc in requests:
            status, answer = real.api(method, path, doc, host=host)
            assert status == 403 and answer["field"] == "Host", (host, answer)
        status, headers, _ = real.raw("GET", f"/?token={real.token}", host=host)
        assert status == 403 and "Set-Cookie" not in headers  # no login through another name
    assert real.dataset.read_bytes() == before
    # A request without any Host (HTTP/1.0) is refused too.
    with socket.create_connection(("127.0.0.1", port), timeout=10) as raw:
        raw.sendall(f"GET /api/session HTTP/1.0\r\nX-Handeye-Token: {real.token}\r\n\r\n".encode())
        answer = b"".join(iter(lambda: raw.recv(65536), b""))
    assert answer.startswith(b"HTTP/1.1 403") and b'"field": "Host"' in answer
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"LOCALHOST:{port}"):
        assert real.api("GET", "/api/session", host=host)[0] == 200, host


def test_an_origin_that_is_not_the_servers_page_is_refused(real):
    before = real.dataset.read_bytes()
    tablet_px = load_dataset(real.dataset).tablet_px.tolist()
    body = calibration_body(tablet_px, [[5.0, 5.0]] * 9)
    port = real.port
    for origin in ("http://attacker.example", f"http://127.0.0.1:{port + 1}", "null",
                   f"https://127.0.0.1:{port}", f"http://localhost:{port}", "garbage"):  # fmt: skip
        for method, path, doc in (("GET", "/api/session", None), ("POST", "/api/calibration", body),
                                  ("OPTIONS", "/api/calibration", None)):  # fmt: skip
            status, answer = real.api(method, path, doc, {"Origin": origin})
            assert status == 403 and answer["field"] == "Origin", (origin, method, answer)
    assert real.dataset.read_bytes() == before
    # A fetch that the browser marks as made by another site is refused as well.
    status, answer = real.api("GET", "/api/session", headers={"Sec-Fetch-Site": "same-site"})
    assert status == 403 and answer["field"] == "Sec-Fetch-Site"
    own = {"Origin": f"http://127.0.0.1:{port}", "Sec-Fetch-Site": "same-origin"}
    assert real.api("GET", "/api/session", headers=own)[0] == 200


def test_an_oversized_content_length_gets_413_at_once(real):
    """Issue 16: it waited 30 s for the body, then said 500 TimeoutError."""
    for length in (MAX_BODY_BYTES + 1, 10**12):
        with socket.create_connection(("127.0.0.1", real.port), timeout=10) as raw:
            t0 = time.monotonic()
            raw.sendall(f"POST /api/evaluation HTTP/1.1\r\nHost: 127.0.0.1:{real.port}\r\n"
                        f"X-Handeye-Token: {real.token}\r\nContent-Type: application/json\r\n"
                        f"Content-Length: {length}\r\n\r\n".encode())  # fmt: skip
            answer = b"".join(iter(lambda raw=raw: raw.recv(65536), b""))  # until it closes
            waited = time.monotonic() - t0
        assert answer.startswith(b"HTTP/1.1 413"), answer[:100]
        assert f"body of {length} bytes is over the limit".encode() in answer
        assert waited < 2.0, waited  # not request_timeout_s (30 s)
    # A client that sends its whole oversized body reads the 413 too (not a reset).
    status, headers, raw = real.raw("POST", "/api/evaluation", {
        "X-Handeye-Token": real.token, "Content-Type": "application/json"},
        b"x" * (MAX_BODY_BYTES + 1))  # fmt: skip
    assert status == 413 and headers["Connection"] == "close"


def test_head_is_answered_like_get_without_a_body(real):
    for path in ("/", "/app.js", "/style.css", "/api/session",
                 "/api/grid?cols=2&rows=2&left=0&top=0&right=9&bottom=9"):  # fmt: skip
        headers = {"Cookie": f"handeye-jax-token-{real.port}={real.token}"}
        got, got_headers, got_body = real.raw("GET", path, headers)
        head, head_headers, head_body = real.raw("HEAD", path, headers)
        assert got == head == 200 and head_body == b"" and len(got_body) > 0, path
        for key in ("Content-Type", "Content-Length", "Cache-Control"):
            assert head_headers[key] == got_headers[key], (path, key)
        assert int(head_headers["Content-Length"]) == len(got_body)
    assert real.raw("HEAD", "/api/session")[0] == 403  # and it is guarded the same way


def test_malformed_queries_and_pathological_bodies_get_400_not_a_dropped_line(real):
    grid = "/api/grid?cols=3&rows=3&left=0&top=0&right=900&bottom=900"
    for name, value in (
        ("cols", "nan"), ("cols", "1e400"), ("rows", "inf"), ("left", "-nan"),
        ("right", "1e400"), ("top", "1" * 60), ("cols", "2.5"), ("cols", ""),
    ):  # fmt: skip
        status, answer = real.api("GET", re.sub(rf"{name}=[^&]*", f"{name}={value}", grid))
        assert status == 400 and answer["field"] == name, (name, value, answer)
    status, answer = real.api("GET", grid + "&x=1" * 30)
    assert status == 400 and "too many fields" in answer["error"]
    bodies = [
        (400, b"[" * 60_000, "nested too deep"),  # Python's json: RecursionError
        (413, b"[" * 100_000, "over the limit"),  # bigger than any run
        (400, b"1" * 5_000, "too many digits"),  # Python's int(): ValueError past 4300 digits
        (400, b'{"run_id": ' + b"9" * 5_000 + b"}", "too many digits"),
        (
            400,
            b'{"run_id": "r", "label": "l", "targets": "grid", "touches": [{"m": 0, '
            b'"target_px": [1, 2], "touch_px": [1e99999, 2], "pointer_type": "pen"}]}',
            "must be a finite number",
        ),  # fmt: skip
    ]
    for status, body, text in bodies:
        got, _, raw = real.raw("POST", "/api/evaluation", {
            "X-Handeye-Token": real.token, "Content-Type": "application/json"}, body)  # fmt: skip
        answer = json.loads(raw)
        assert got == status and text in answer["error"] + answer["field"], (body[:20], answer)
    assert real.api("GET", "/api/session")[0] == 200  # and the server goes on


def _open_without_accept(port, n):
    """``n`` connections begun at once; those the kernel completes within 0.5 s."""
    socks = []
    for _ in range(n):
        s = socket.socket()
        s.setblocking(False)
        s.connect_ex(("127.0.0.1", port))
        socks.append(s)
    time.sleep(0.5)
    _, ready, _ = select.select([], socks, [], 0)
    return socks, [s for s in ready if s.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR) == 0]


def test_fifty_concurrent_posts_get_in_while_the_server_is_busy(real):
    """Issue 16: 7-21 of 50 concurrent posts were reset (a listen backlog of 5)."""
    n = 50
    real.proc.send_signal(signal.SIGSTOP)  # busy: accepting nothing for a moment
    try:
        socks, connected = _open_without_accept(real.port, n)
    finally:
        real.proc.send_signal(signal.SIGCONT)
    assert len(connected) == n, f"{len(connected)} of {n} connections queued"
    touches = [{"m": m, "target_px": [10.0 * m, 20.0], "touch_px": [10.0 * m + 3, 24.0],
                "pointer_type": "pen"} for m in range(9)]  # fmt: skip
    answers = [None] * n

    def post(i, s):
        body = json.dumps({"run_id": f"busy-{i}", "label": "busy", "targets": "grid",
                           "touches": touches}).encode()  # fmt: skip
        s.setblocking(True)
        s.settimeout(30)
        try:
            s.sendall(f"POST /api/evaluation HTTP/1.1\r\nHost: 127.0.0.1:{real.port}\r\n"
                      f"X-Handeye-Token: {real.token}\r\nContent-Type: application/json\r\n"
                      f"Content-Length: {len(body)}\r\n\r\n".encode() + body)  # fmt: skip
            answers[i] = b"".join(iter(lambda: s.recv(65536), b"")).split(b"\r\n")[0]
        except OSError as e:  # a reset or a timeout
            answers[i] = repr(e).encode()
        finally:
            s.close()

    threads = [threading.Thread(target=post, args=(i, s)) for i, s in enumerate(socks)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert answers == [b"HTTP/1.1 200 OK"] * n
    saved = json.loads(real.dataset.with_name("rig.trials.json").read_text())["trials"]
    assert sorted(t["run_id"] for t in saved if t["label"] == "busy") == sorted(
        f"busy-{i}" for i in range(n)
    )


def test_a_calibration_run_of_one_landmark_is_taken(tmp_path):
    """Any number of landmarks from one (issue 17: a few touches after a pen change)."""
    full = load_dataset(PAPER)
    fields = ("tablet_px", "image_px", "depth_mm", "hand_xy_mm", "hand_angle_deg",
              "touch_error_px")  # fmt: skip
    ds = tmp_path / "rig.toml"
    save_dataset(full.replace(**{f: getattr(full, f)[[4]] for f in fields}), ds)
    server = start(ds)
    try:
        tablet_px = load_dataset(ds).tablet_px.tolist()
        status, doc = request(server.url + "api/calibration",
                              calibration_body(tablet_px, [[1.5, -2.0]]))  # fmt: skip
        assert status == 200 and doc["written"] is True, doc
        assert load_dataset(ds).touch_error_px.tolist() == [[1.5, -2.0]]
        status, doc = request(server.url + "api/calibration",
                              calibration_body(tablet_px * 2, [[1.5, -2.0]] * 2))  # fmt: skip
        assert status == 400 and "needs one touch per landmark: 1 (got 2)" in json.dumps(doc)
    finally:
        stop(server)


def test_a_v2_dataset_takes_the_touch_errors_or_refuses_touches_out_of_order(tmp_path):
    paper = load_dataset(PAPER)
    ds = tmp_path / "rig.toml"
    first = paper.captures[0]
    errors = np.full((9, 2), 1.5)
    for order, expect in ((np.arange(9), 200), (np.r_[1, 0, 2:9], 409)):
        two = paper.replace(captures=[first, first], touch_landmark=order)
        save_dataset(two, ds)
        before = ds.read_bytes()
        server = start(ds)
        try:
            body = calibration_body(paper.tablet_px.tolist(), errors)
            status, doc = request(server.url + "api/calibration", body)
        finally:
            stop(server)
        assert status == expect, doc
        if expect == 200:
            assert load_dataset(ds) == two.replace(touch_error_px=errors)
        else:
            assert "one [[touches]] per landmark in landmark order" in doc["error"]
            assert ds.read_bytes() == before


# -- issue 23: a stranger cannot stall the server, flood its log or write to its terminal ------


def _attack_module():
    """``benchmarks/tablet_attack.py``: the attacks the acceptance is measured with."""
    spec = importlib.util.spec_from_file_location("tablet_attack", BENCH / "tablet_attack.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_slow_connections_under_ulimit_1024_leave_the_operator_answered(tmp_path):
    """Issue 23: with ``ulimit -n 1024``, 1,100 connections sending one header line every few
    seconds left the operator unanswered, and the accept loop spun at ~96 % of a core on
    EMFILE. Here 1,100 such connections (reopened when closed, as slowloris does) hold on
    while the operator asks every 0.25 s; the server runs under RLIMIT_NOFILE 1024."""
    attack = _attack_module()
    attack.raise_own_file_limit(1400)
    server = attack.Server("tablet", tmp_path, REPO, nofile=1024)
    try:
        got = attack.slow_attack(server, 1100, seconds=4.0, drip_s=1.0)
        after = server.ask(timeout_s=5.0)
    finally:
        server.stop()
    assert got["asked"] >= 5 and got["answered"] == got["asked"], got
    assert got["median_s"] < 1.0 and got["max_s"] < 2.0, got  # the acceptance: <= 1 s
    assert got["cpu_core"] < 0.3, got  # no spin (benchmarks/tablet_attack.py measures ~5 %)
    assert after is not None and b"Traceback" not in server.log


def test_a_request_that_trickles_in_is_cut_at_its_deadline(tmp_path):
    """Issue 23: the time-out was per read, so a header line every few seconds held a
    connection forever; now the whole head (and body) has one deadline."""
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    server = start(ds, request_timeout_s=1.0)
    try:
        with socket.create_connection(("127.0.0.1", server.port), timeout=10) as s:
            s.sendall(f"GET /api/session HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\n".encode())
            t0, answer = time.monotonic(), b""
            while time.monotonic() - t0 < 6 and not answer:
                try:  # a line every 0.3 s, each within any per-read time-out
                    s.sendall(b"X-Slow: 1\r\n")
                    ready, _, _ = select.select([s], [], [], 0.3)
                    answer = s.recv(65536) if ready else b""
                except OSError:
                    break
            waited = time.monotonic() - t0
        assert answer.startswith(b"HTTP/1.1 408"), answer
        assert waited < 3.0 and b"did not arrive whole within 1 s" in answer
        assert request(server.url + "api/session")[0] == 200
    finally:
        stop(server)


def test_reset_connections_add_one_log_line_each_at_most(real):
    """Issue 23: 200 connections reset by the client printed 11,200 traceback lines."""
    time.sleep(0.5)
    before = len(real.log)
    for _ in range(200):
        with socket.create_connection(("127.0.0.1", real.port), timeout=10) as s:
            s.sendall(b"POST /api/calibration HTTP/1.1\r\nContent-Length: 100\r\n")
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    time.sleep(1.0)
    added = real.log[before:]
    assert len(added) <= 200, added[:5]
    assert not any("Traceback" in line or line.startswith("  File") for line in added)
    assert real.api("GET", "/api/session")[0] == 200


def test_no_control_byte_of_a_request_reaches_the_terminal(real):
    """Issue 23: ESC and OSC bytes of a request path were written raw to the operator's
    terminal (a retitled window, a cleared screen)."""
    time.sleep(0.3)
    before = len(real.log)
    for path in (b"/\x1b]0;pwned\x07\x1b[2J", b"/x\x9b31mred", b"/%1b]0;t%07"):
        with socket.create_connection(("127.0.0.1", real.port), timeout=10) as s:
            s.sendall(b"GET " + path + f" HTTP/1.1\r\nHost: 127.0.0.1:{real.port}\r\n"
                      f"Connection: close\r\n\r\n".encode())  # fmt: skip
            assert b"".join(iter(lambda s=s: s.recv(65536), b"")).startswith(b"HTTP/1.")
    time.sleep(0.5)
    logged = "".join(real.log[before:])
    assert len(real.log) > before
    assert not any(c in logged for c in "\x1b\x07\x9b"), logged
    # Nor from a header the log names (a refused Host).
    status, _, _ = real.raw("GET", "/api/session", {"X-Handeye-Token": real.token},
                            host="\x1b[2J\x9b")  # fmt: skip
    assert status in (400, 403)
    time.sleep(0.5)
    assert not any(c in "".join(real.log[before:]) for c in "\x1b\x07\x9b")


def test_the_secret_is_blanked_in_the_log_however_it_is_spelt(real):
    """Issue 23: ``%74oken=`` was taken as the token but not blanked in the log."""
    for spelt in ("%74oken", "t%6Fken", "%74%6F%6B%65%6E"):
        status, headers, _ = real.raw("GET", f"/?{spelt}={real.token}")
        assert status == 303 and "Set-Cookie" in headers, spelt
        line = real.wait_log(f"GET /?{spelt}=")
        assert f"{spelt}=[secret]" in line
    time.sleep(0.3)
    assert not any(real.token in line for line in real.log)


def test_numbers_and_lengths_are_plain_ascii_digits(real):
    """Issue 23: ``/api/grid`` and ``Content-Length`` took ``３``, ``1_0`` and ``+10``."""
    grid = "/api/grid?cols=3&rows=3&left=0&top=0&right=900&bottom=900"
    for value in ("３", "1_0", "+10", " 3", "3.", "0x3", "٣"):
        quoted = urllib.parse.quote(value)
        status, answer = real.api("GET", grid.replace("cols=3", f"cols={quoted}"))
        assert status == 400 and answer["field"] == "cols", (value, answer)
    assert real.api("GET", grid)[0] == 200
    body = json.dumps({"run_id": "r"}).encode()
    for length in ("３".encode(), b"1_0", b"+10", b"0x10", b"1e1"):
        head = (f"POST /api/evaluation HTTP/1.1\r\nHost: 127.0.0.1:{real.port}\r\n"
                f"X-Handeye-Token: {real.token}\r\nContent-Type: application/json\r\n")  # fmt: skip
        with socket.create_connection(("127.0.0.1", real.port), timeout=10) as s:
            s.sendall(head.encode() + b"Content-Length: " + length + b"\r\n\r\n" + body)
            answer = b"".join(iter(lambda s=s: s.recv(65536), b""))
        assert answer.startswith(b"HTTP/1.1 400"), (length, answer[:200])


def test_a_huge_integer_and_a_nan_are_refused_by_name(served):
    """Issue 23: a 4,000-digit integer gave 500 OverflowError; ``NaN`` was reported as "a
    number with too many digits"."""
    url, _ = served
    touch = '{"m": 0, "target_px": [%s, 2], "touch_px": [1, 2], "pointer_type": "pen"}'
    head = '{"run_id": "r", "label": "l", "targets": "grid", "touches": [%s]}'
    for number, text in (("9" * 4000, "an integer of 4000 digits"),
                         ("-" + "9" * 4000, "an integer of 4000 digits"),
                         ("NaN", "NaN is not a number"), ("-Infinity", "-Infinity is not a "
                                                                      "number")):  # fmt: skip
        status, doc = request(url + "api/evaluation", (head % (touch % number)).encode())
        assert status == 400 and text in doc["error"], (number[:10], doc)


def test_a_label_that_is_not_printable_is_refused_and_an_old_one_never_breaks_a_stop(tmp_path):
    """Issue 23: a lone-surrogate label made every later stop exit 1 (UnicodeEncodeError),
    even after a restart; ESC in a label reached the terminal in the exit summary."""
    old = new_trials(267.0, 2.0)
    record = {"trial": 1, "run_id": "old", "mean_px": 1.0, "max_px": 2.0, "mean_mm": 0.19,
              "max_mm": 0.38}  # fmt: skip
    old["trials"] = [{**record, "label": "\ud800 lone"}, {**record, "label": "\x1b]0;x\x07 esc"}]
    trials = tmp_path / "rig.trials.json"
    trials.write_text(json.dumps(old))  # as a server before this fix saved them
    server = ServerProcess(tmp_path)
    touch = {"m": 0, "target_px": [10.0, 20.0], "touch_px": [13.0, 24.0], "pointer_type": "pen"}
    body = b'{"run_id": "new", "label": "%s", "targets": "grid", "touches": [%s]}'
    for label in (b"\\ud800", b"\\u001b[2J", b"a\\u202eb", b"\\u0007"):
        status, _, raw = server.raw("POST", "/api/evaluation", {
            "X-Handeye-Token": server.token, "Content-Type": "application/json"},
            body % (label, json.dumps(touch).encode()))  # fmt: skip
        assert status == 400 and json.loads(raw)["field"] == "label", (label, raw)
    status, doc = server.api(
        "POST",
        "/api/evaluation",
        {"run_id": "ok", "label": "stage 2", "targets": "grid", "touches": [touch]},
    )
    assert status == 200, doc
    out = server.stop()
    assert server.proc.returncode == 0, out
    assert "\\ud800 lone: mean touching error" in out and "\\x1b]0;x\\x07 esc" in out
    assert "\x1b" not in out and "\x07" not in out and "stage 2: mean" in out


def test_backups_are_the_first_and_the_last_fifty(tmp_path):
    """Issue 23: one client posting 96 times a second filled a disk with backups."""
    ds = tmp_path / "rig.toml"
    shutil.copy(PAPER, ds)
    original = ds.read_bytes()
    tablet_px = load_dataset(ds).tablet_px
    versions = []
    for k in range(60):
        post = parse_calibration(calibration_body(tablet_px.tolist(), [[k * 0.5, 1.0]] * 9), 9)
        versions.append(ds.read_bytes())
        assert apply_touch_errors(ds, post) is not None
    kept = backups(tmp_path)
    assert len(kept) == 1 + MAX_BACKUPS
    assert kept[0].read_bytes() == original  # the first, always
    assert [p.read_bytes() for p in kept[1:]] == versions[-MAX_BACKUPS:]
    other = tmp_path / "rig.toml.mine.bak"
    other.write_text("not a version")  # another file is never removed
    assert prune_backups(ds, keep=2) == kept[1:-2]
    assert other.exists() and sorted(tmp_path.glob("rig.toml.2*.bak")) == [kept[0], *kept[-2:]]


def test_dataset_saves_are_limited_in_rate(served):
    """Issue 23: a client could save (and back up) the dataset 96 times a second."""
    url, ds = served
    tablet_px = load_dataset(ds).tablet_px.tolist()
    answers = [request(url + "api/calibration", calibration_body(tablet_px, [[k, 0.0]] * 9,
                                                                 f"r{k}"))
               for k in range(SAVE_BURST + 3)]  # fmt: skip
    statuses = [status for status, _ in answers]
    assert statuses[:SAVE_BURST] == [200] * SAVE_BURST and 429 in statuses[SAVE_BURST:]
    refused = next(doc for status, doc in answers if status == 429)
    assert "saved" in refused["error"] and "again" in refused["error"]
    assert len(backups(ds.parent)) == statuses.count(200)
