"""Unbounded inputs (issue 16, section 3): every loader refuses, in one line and in seconds,
what is not a regular file, what is larger than its cap, and text that breaks the standard
library's parsers (deep nesting, huge integers, huge CSV fields)."""

import json
import os
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from handeye_jax import InputError, load_dataset, load_heldout, load_result, load_truth
from handeye_jax._core import MAX_DATASET_BYTES, MAX_IMAGE_BYTES, MAX_RESULT_BYTES, MAX_TEXT_BYTES
from handeye_jax.cli import main
from handeye_jax.data import read_points_csv
from handeye_jax.tablet import load_targets, load_trials
from handeye_jax.vision import read_image

PAPER = Path(__file__).resolve().parents[1] / "data" / "paper2023.toml"

# name: (loader, suffix, cap in bytes)
LOADERS = {
    "dataset": (load_dataset, ".toml", MAX_DATASET_BYTES),
    "result": (load_result, ".json", MAX_RESULT_BYTES),
    "truth": (load_truth, ".json", MAX_TEXT_BYTES),
    "targets": (load_targets, ".json", MAX_TEXT_BYTES),
    "trials": (lambda p: load_trials(p, 267.0, 2.0), ".json", MAX_TEXT_BYTES),
    "points": (read_points_csv, ".csv", MAX_TEXT_BYTES),
    "heldout": (load_heldout, ".csv", MAX_TEXT_BYTES),
    "image": (read_image, ".png", MAX_IMAGE_BYTES),
}
JSON_LOADERS = ("result", "truth", "targets", "trials")
CSV_LOADERS = ("points", "heldout")


def _error_within(seconds: float, fn, *args) -> InputError:
    """The InputError ``fn(*args)`` raises, in a thread that must finish within ``seconds``
    (a FIFO read with a blocking open would hang for ever; the thread is a daemon)."""
    outcome: list = []

    def run():
        try:
            outcome.append(fn(*args))
        except BaseException as e:  # noqa: BLE001 - handed to the test
            outcome.append(e)

    worker = threading.Thread(target=run, daemon=True)
    t0 = time.perf_counter()
    worker.start()
    worker.join(seconds)
    assert not worker.is_alive(), f"{fn} still running after {seconds} s"
    assert isinstance(outcome[0], InputError), outcome[0]
    assert time.perf_counter() - t0 < seconds
    return outcome[0]


def _special(tmp_path: Path, kind: str, suffix: str) -> Path:
    path = tmp_path / f"{kind}{suffix}"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    else:
        path.symlink_to(f"/dev/{kind}")
    return path


@pytest.mark.parametrize("kind", ["fifo", "zero", "urandom", "folder"])
@pytest.mark.parametrize("name", list(LOADERS))
def test_every_loader_refuses_what_is_not_a_regular_file(tmp_path, name, kind):
    load, suffix, _ = LOADERS[name]
    path = _special(tmp_path, kind, suffix)
    e = _error_within(10, load, path)
    assert e.path == path and "not a regular file" in str(e) and "\n" not in str(e)


@pytest.mark.parametrize("name", list(LOADERS))
def test_every_loader_refuses_a_file_over_its_cap(tmp_path, name):
    load, suffix, cap = LOADERS[name]
    path = tmp_path / f"big{suffix}"
    with open(path, "wb") as f:
        f.truncate(cap + 1)  # sparse: no disk space used
    e = _error_within(10, load, path)
    assert e.path == path and "larger than" in str(e) and f"{cap // 2**20} MiB" in str(e)


NESTED = {"json": "[" * 5000 + "]" * 5000, "toml": "name = " + "[" * 5000 + "]" * 5000 + "\n"}
DIGITS = {"json": '{"format": 1' + "0" * 5000 + "}", "toml": "name = 1" + "0" * 5000 + "\n"}


@pytest.mark.parametrize("name", ["dataset", *JSON_LOADERS])
@pytest.mark.parametrize("text,says", [(NESTED, "nested too deeply"), (DIGITS, "5,000 digits")],
                         ids=["nested", "digits"])  # fmt: skip
def test_deep_nesting_and_huge_integers_are_one_line_errors(tmp_path, name, text, says):
    load, suffix, _ = LOADERS[name]
    path = tmp_path / f"hostile{suffix}"
    path.write_text(text[suffix[1:]])
    e = _error_within(10, load, path)
    assert e.path == path and "\n" not in str(e)
    if says == "5,000 digits":  # Python's limit is 4,300; the message gives the count or limit
        assert "an integer of 5001 digits" in str(e) or "more than 4,300 digits" in str(e), e
    else:
        assert says in str(e)


@pytest.mark.parametrize("name", CSV_LOADERS)
def test_a_csv_field_over_the_csv_modules_limit_names_its_line(tmp_path, name):
    load, suffix, _ = LOADERS[name]
    path = tmp_path / f"wide{suffix}"
    path.write_text("u,v,depth,hand_angle,tablet_x,tablet_y\n1,2,3,4,5,6\n" + "9" * 200_000 + "\n")
    e = _error_within(10, load, path)
    assert e.field == "line 3" and "longer than 131,072 characters" in e.message


def test_the_command_line_refuses_special_files_in_one_line(tmp_path, capsys):
    fifo = _special(tmp_path, "fifo", ".toml")
    zero = _special(tmp_path, "zero", ".json")
    rnd = _special(tmp_path, "urandom", ".csv")
    pts = tmp_path / "pts.csv"
    pts.write_text("u,v,depth,hand_angle\n338,244,169.2,90\n")
    for argv, named in [
        (["calibrate", str(fifo), "--quiet"], fifo),
        (["predict", str(zero), str(pts)], zero),
        (["evaluate", str(zero), str(tmp_path)], zero),
        (["simulate", str(tmp_path / "twin"), "--truth", str(zero)], zero),
        (["detect", str(rnd), str(rnd), "--dataset", str(PAPER), "--out",
          str(tmp_path / "o.toml")], rnd),
    ]:  # fmt: skip
        t0 = time.perf_counter()
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"{named}: cannot read" in err and "not a regular" in err
        assert time.perf_counter() - t0 < 10
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "fifo.toml", "pts.csv", "urandom.csv", "zero.json"
    ]  # fmt: skip


def _png_header(width: int, height: int) -> bytes:
    ok, png = cv2.imencode(".png", np.zeros((8, 8), np.uint8))
    data = bytearray(png.tobytes())
    data[16:24] = width.to_bytes(4, "big") + height.to_bytes(4, "big")
    return bytes(data)


def _jpeg_header(width: int, height: int) -> bytes:
    ok, jpg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))
    data = bytearray(jpg.tobytes())
    sof = data.index(b"\xff\xc0")  # baseline frame header: length, precision, height, width
    data[sof + 5 : sof + 9] = height.to_bytes(2, "big") + width.to_bytes(2, "big")
    return bytes(data)


@pytest.mark.parametrize(
    "make,side,says",
    [
        # 30,000 x 30,000 is under OpenCV's own limit (2^30 px): it would allocate 900 MB.
        (_png_header, 30_000, "too large (30000x30000 px; at most 16,777,216 px"),
        (_jpeg_header, 8_000, "too large (8000x8000 px; at most 16,777,216 px"),
        (_jpeg_header, 20_000, "too large (more than 178,956,970 px)"),  # Pillow's own limit
    ],
)
def test_an_image_whose_header_is_too_large_is_refused_before_decoding(tmp_path, make, side,
                                                                      says):  # fmt: skip
    path = tmp_path / "bomb"
    path.write_bytes(make(side, side))
    e = _error_within(10, read_image, path)
    assert e.path == path and says in e.message


def test_the_largest_documented_dataset_loads_in_seconds(tmp_path, capsys):
    # 10,000 landmarks (the limit) load; 10,001 are refused by name, both within seconds.
    from handeye_jax._core import MAX_LANDMARKS

    text = PAPER.read_text()
    head, first = text.split("[[landmarks]]")[:2]
    mark = "[[landmarks]]" + first.rstrip() + "\n"
    rows = []
    for i in range(MAX_LANDMARKS + 1):
        rows.append(mark.replace("tablet_px = [400.0, 150.0]", f"tablet_px = [{i}.0, 1.0]"))
    path = tmp_path / "many.toml"
    path.write_text(head + "\n".join(rows[:MAX_LANDMARKS]))
    t0 = time.perf_counter()
    assert load_dataset(path).n_landmarks == MAX_LANDMARKS
    # DE's memory grows with population x landmarks: refused before any work.
    assert main(["calibrate", str(path), "--population", "100000", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{path}: landmarks: 10,000 landmarks with a DE population of 100,000 need about " \
        "48 GB; use a population of at most 10,000" in err, err  # fmt: skip
    path.write_text(head + "\n".join(rows))
    e = _error_within(20, load_dataset, path)
    assert e.field == "landmarks" and "has 10,001 landmarks; at most 10,000" in e.message
    assert time.perf_counter() - t0 < 20


def test_json_loaders_name_a_repeated_key(tmp_path):
    path = tmp_path / "targets.json"
    path.write_text('{"tablet_px": [[1, 2]], "tablet_px": [[3, 4]]}')
    e = _error_within(10, load_targets, path)
    assert e.field == "tablet_px" and "duplicate key" in e.message
    path.write_text(json.dumps({"tablet_px": [[1, 2]]}))
    np.testing.assert_array_equal(load_targets(path), [[1, 2]])


def test_sizes_inside_a_file_are_bounded_too(tmp_path):
    # Rows of a points CSV: reading stops one row past the limit.
    from handeye_jax._core import MAX_POINTS

    pts = tmp_path / "many.csv"
    pts.write_text("u,v,depth,hand_angle\n" + "338,244,169.2,90\n" * (MAX_POINTS + 1))
    e = _error_within(10, read_points_csv, pts)
    assert e.field == "rows" and "has more than 100,000 points" in e.message
    pts.write_text("u,v,depth,hand_angle\n" + "338,244,169.2,90\n" * 3 + "\n" * 1_000_000)
    assert read_points_csv(pts)[2].shape == (3, 4)  # blank lines cost nothing
    # Objects in a JSON file: 3 MiB of {} would be a million dicts.
    targets = tmp_path / "objects.json"
    targets.write_text("[" + "{}," * 1_000_001 + "{}]")
    e = _error_within(10, load_targets, targets)
    assert "not valid here: more than 1,000,000 objects" in e.message
