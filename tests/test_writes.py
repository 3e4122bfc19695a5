"""Every atomic writer (issue 23): through a symbolic link to the file it names, and leaving no
temporary file of ours behind for long, even after a SIGKILL in the middle of a write.

A write to a link replaces the link's target and the link stays a link (the file the link
names gets the new values, as ``open(link, "w")`` would give it, but whole or not at all);
the temporaries a killed writer left beside a file go at the next write to that file.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from test_predictor import _fixed_case

import handeye_jax._core._atomic as _atomic
from handeye_jax import InputError, load_dataset, save_dataset, save_result, update_dataset
from handeye_jax.cli import main
from handeye_jax.data import backup_path

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "data" / "paper2023.toml"
POINTS = "u,v,depth,hand_angle\n338,244,169.2,90\n119,105,168.2,0\n"


def _linked(tmp_path: Path, name: str, text: str = "old\n") -> tuple[Path, Path]:
    """A file ``store/name`` and a link ``work/name`` to it."""
    (tmp_path / "store").mkdir(exist_ok=True)
    (tmp_path / "work").mkdir(exist_ok=True)
    target = tmp_path / "store" / name
    target.write_text(text)
    link = tmp_path / "work" / name
    link.symlink_to(target)
    return link, target


def _hidden(*folders: Path) -> list[str]:
    return sorted(p.name for f in folders for p in f.iterdir() if p.name.startswith("."))


def test_the_atomic_writers_write_through_a_link(tmp_path):
    link, target = _linked(tmp_path, "out.txt")
    _atomic.write_output(link, "new\n", "--out")
    assert link.is_symlink() and target.read_text() == "new\n"
    # several files at once (a report's figures, a dataset and its backup)
    link2, target2 = _linked(tmp_path, "other.txt")
    _atomic.StagedFiles({link: b"a\n", link2: b"b\n"}).commit()
    assert link.is_symlink() and link2.is_symlink()
    assert (target.read_text(), target2.read_text()) == ("a\n", "b\n")
    # a link to a file not yet there: made where the link points
    dangling = tmp_path / "work" / "later.txt"
    dangling.symlink_to(tmp_path / "store" / "later.txt")
    _atomic.write_output(dangling, "made\n")
    assert dangling.is_symlink() and (tmp_path / "store" / "later.txt").read_text() == "made\n"
    assert _hidden(tmp_path / "work", tmp_path / "store") == []
    # a loop of links is refused in one line, nothing written
    loop = tmp_path / "work" / "loop.txt"
    loop.symlink_to(loop)
    with pytest.raises(InputError, match=r"loop.txt: --out: cannot write: .*symbolic links"):
        _atomic.write_output(loop, "x", "--out")
    assert loop.is_symlink()


def test_dataset_saves_write_through_a_link(tmp_path):
    """``save_dataset``, and ``update_dataset`` as the tablet saves touching errors (a new
    backup beside the link, the linked file changed, its comments kept)."""
    paper = load_dataset(PAPER)
    link, target = _linked(tmp_path, "paper.toml", PAPER.read_text())
    changed = paper.replace(touch_error_px=paper.touch_error_px + 1.0)
    backup = backup_path(link)
    assert update_dataset(link, changed, keep_backup=True, backup=backup) == backup
    assert link.is_symlink() and load_dataset(target) == changed
    assert target.read_text().startswith("# The published data")  # comments kept
    assert not backup.is_symlink() and backup.read_text() == PAPER.read_text()
    save_dataset(paper, link)
    assert link.is_symlink() and load_dataset(target) == paper
    assert _hidden(tmp_path / "work", tmp_path / "store") == []


def _result(path: Path) -> None:
    """A result file (the predictor tests' case: no fit needed), written by the toolkit."""
    save_result(_fixed_case().result(), path)


def test_command_outputs_write_through_a_link(tmp_path, capsys):
    """A result (``save_result``, as ``calibrate --out`` writes it), ``predict --out`` and
    ``export --out`` to links."""
    result, result_target = _linked(tmp_path, "result.json")
    _result(result)
    assert result.is_symlink() and result_target.read_text().startswith("{")
    points = tmp_path / "points.csv"
    points.write_text(POINTS)
    csv, csv_target = _linked(tmp_path, "commands.csv")
    assert main(["predict", str(result), str(points), "--out", str(csv)]) == 0
    assert csv.is_symlink() and csv_target.read_text().startswith("u,v,depth,hand_angle,hand_x")
    urdf, urdf_target = _linked(tmp_path, "rig.urdf")
    assert main(["export", str(result), "--format", "urdf", "--stage", "1",
                 "--out", str(urdf)]) == 0  # fmt: skip
    assert urdf.is_symlink() and "<joint" in urdf_target.read_text()
    assert _hidden(tmp_path / "work", tmp_path / "store") == []


# -- temporary files a killed writer left ----------------------------------------------------

KILLED_WRITER = textwrap.dedent(
    """
    import os, signal, sys
    from pathlib import Path
    from handeye_jax._core import _atomic
    path = Path(sys.argv[1])
    _atomic.StagedFiles({path: b"half"})  # temporaries written, not yet put in place
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


def _killed_while_writing(path: Path) -> list[str]:
    """What a SIGKILL in the middle of writing ``path`` leaves beside it (names)."""
    before = set(os.listdir(path.parent))
    p = subprocess.run([sys.executable, "-c", KILLED_WRITER, str(path)], cwd=ROOT,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120)  # fmt: skip
    assert p.returncode == -signal.SIGKILL
    return sorted(set(os.listdir(path.parent)) - before)


def _age(folder: Path, name: str, seconds: float) -> None:
    t = time.time() - seconds
    os.utime(folder / name, (t, t))


def test_the_next_write_sweeps_what_a_killed_writer_left(tmp_path):
    out = tmp_path / "result.json"
    out.write_text("precious\n")
    (left,) = _killed_while_writing(out)
    assert left.startswith(".result.json.") and left.endswith(".tmp")
    assert out.read_text() == "precious\n"
    _age(tmp_path, left, 60)  # its process ended a minute ago
    # Not ours, or not stale: kept. Ours from a live process (this one), ours without a
    # process number (an older version's) but recent, another file's, a user's own files.
    mine = f".result.json.{os.getpid()}.abcd_123.tmp"
    keep = [mine, ".result.json.abcd1234.tmp", ".other.json.12.abcd1234.tmp", ".result.json.x.tmp",
            "result.json.abcd1234.tmp", ".result.json.abcd1234.bak"]  # fmt: skip
    for name in keep:
        (tmp_path / name).write_text("x")
        _age(tmp_path, name, 60)
    old = ".result.json.zyxw9876.tmp"  # an older version's, a day old
    (tmp_path / old).write_text("x")
    _age(tmp_path, old, 24 * 3600)
    _atomic.write_output(out, "new\n")
    assert out.read_text() == "new\n"
    assert sorted(os.listdir(tmp_path)) == sorted(["result.json", *keep])


def test_a_fresh_leftover_waits_and_a_later_command_sweeps_it(tmp_path, capsys):
    """Just after the kill a leftover stays (a writer on another machine sharing the folder
    could own its number, for ORPHAN_AFTER_S = 10 s); ``predict --out`` later sweeps it."""
    out = tmp_path / "commands.csv"
    (left,) = _killed_while_writing(out)
    points = tmp_path / "points.csv"
    points.write_text(POINTS)
    result = tmp_path / "result.json"
    _result(result)
    argv = ["predict", str(result), str(points), "--out", str(out)]
    assert main(argv) == 0
    assert sorted(os.listdir(tmp_path)) == sorted([left, "commands.csv", "points.csv",
                                                  "result.json"])  # fmt: skip
    _age(tmp_path, left, 60)
    assert main(argv) == 0
    assert sorted(os.listdir(tmp_path)) == ["commands.csv", "points.csv", "result.json"]
    assert np.loadtxt(out, delimiter=",", skiprows=1).shape == (2, 6)
