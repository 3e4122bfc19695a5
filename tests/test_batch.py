"""calibrate_batch: each problem of a batch reaches its own single run's optimum, however the
batch is made up or split, on one device, on two host devices, and over two processes
(``jax.distributed`` on 127.0.0.1).

The twins are noise-free and tiny (9, 20 and 9 landmarks: the one of 20 is padded to 24
rows) and the budget small, so that the programs compile fast; the subprocesses' results come
back as JSON and are compared with the in-process single runs."""

import dataclasses
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from handeye_jax import Settings, calibrate, calibrate_batch, draw_truth, synthesize_dataset
from handeye_jax.data import snake_grid_px

ROOT = Path(__file__).resolve().parents[1]
#: A budget small enough to compile and run fast; the restarts and refits still run.
SETTINGS = Settings(population=48, generations=60, restarts=4)
#: (truth seed, columns, rows) of each twin's landmark grid.
TWINS = ((3, 3, 3), (5, 5, 4), (6, 3, 3))


#: The twins the subprocesses fit (of one structure, so that the batch is split over the devices
#: or processes; the others' programs are the in-process tests').
SHARED = (0, 2)


def batch_twins():
    """The noise-free twins (landmarks on a grid, hand angles 22.5° apart)."""
    out = []
    for seed, nx, ny in TWINS:
        truth = draw_truth(seed)
        px = snake_grid_px(tuple(np.linspace(400.0, 1040.0, nx)),
                           tuple(np.linspace(150.0, 550.0, ny)))
        ds = synthesize_dataset(truth.htm(), truth.rig(), px, 22.5 * np.arange(len(px)))
        out.append(ds.replace(name=f"twin{seed}"))
    return out


def numbers(results) -> list[dict]:
    """Each result's F and parameters of both stages, and where each stage's DE stopped."""
    return [{"F1": r.stage1.F, "F2": r.stage2.F, "p1": r.stage1.params, "p2": r.stage2.params,
             "stops": [r.stage1.de.generations, r.stage2.de.generations]}
            for r in results]  # fmt: skip


def assert_same(got: list[dict], want: list[dict]) -> None:
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert g["stops"] == w["stops"]  # each problem's own early stop
        for stage in ("1", "2"):
            assert abs(g["F" + stage] - w["F" + stage]) <= 1e-9
            assert g["p" + stage].keys() == w["p" + stage].keys()
            for name, value in w["p" + stage].items():
                assert abs(g["p" + stage][name] - value) <= 1e-6, name


@pytest.fixture(scope="module")
def twins():
    return batch_twins()


@pytest.fixture(scope="module")
def single(twins):
    """Each twin's own calibrate() run, seed 1 + its index."""
    return numbers([calibrate(d, s) for d, s in zip(twins, seeds(len(twins)), strict=True)])


def seeds(n: int) -> list[Settings]:
    return [dataclasses.replace(SETTINGS, seed=1 + i) for i in range(n)]


def test_the_twins_fit_and_one_is_padded(twins, single):
    from handeye_jax.calibration import padded_rows

    assert [d.n_rows for d in twins] == [9, 20, 9]
    assert [padded_rows(d.observations()) for d in twins] == [None, 24, None]
    for s in single:  # noise-free: the truth explains the data, the fit finds a low F
        assert s["F1"] < 0.05 and s["F2"] <= s["F1"] + 1e-9


def test_a_batch_gives_each_problem_its_own_run(twins, single):
    got = calibrate_batch(twins, seeds(len(twins)))
    assert [r.dataset_name for r in got] == [d.name for d in twins]
    assert_same(numbers(got), single)


def test_the_seconds_reported_are_the_calls_own(twins, single, monkeypatch):
    """A result's ``timings_s["total"]`` is the time its fit took, the search's ranges and
    the maximum-likelihood refinements included (each made 0.2 s slower here, to be seen),
    and holds its parts; a batch's problems share its time."""
    import time

    from handeye_jax.calibration import _batch, _pipeline  # the steps slowed down

    def slowed(step):
        def run(*args, **kwargs):
            time.sleep(0.2)
            return step(*args, **kwargs)

        return run

    monkeypatch.setattr(_pipeline, "full_plan", slowed(_pipeline.full_plan))
    monkeypatch.setattr(_batch, "full_plan", slowed(_batch.full_plan))
    monkeypatch.setattr(_batch, "likelihood", slowed(_batch.likelihood))
    t0 = time.perf_counter()
    r = calibrate(twins[0], seeds(1)[0])
    wall = time.perf_counter() - t0
    t = r.timings_s
    assert t["plan"] >= 0.2 and t["stage1_polish"] >= 0.2 and t["stage2_polish"] >= 0.2, t
    parts = t["plan"] + sum(t[f"stage{k}_{p}"] for k in (1, 2) for p in ("de", "polish"))
    assert parts <= t["total"] <= wall
    assert t["total"] > 0.8 * wall, (t, wall)  # nothing the fit does is left out
    t0 = time.perf_counter()
    both = calibrate_batch([twins[0], twins[2]], [seeds(3)[0], seeds(3)[2]])
    wall = time.perf_counter() - t0
    assert all(r.timings_s["plan"] >= 0.2 for r in both)
    total = sum(r.timings_s["total"] for r in both)
    assert 0.8 * wall < total <= wall, (total, wall)


def test_how_the_batch_is_split_changes_nothing(twins, single):
    """Other batches: the problems in another order and one wave per problem."""
    order = [2, 0, 1]
    shuffled = calibrate_batch([twins[i] for i in order], [seeds(3)[i] for i in order])
    assert_same(numbers(shuffled), [single[i] for i in order])
    pair = [0, 2]  # of one structure: one wave, or one wave each
    one_by_one = calibrate_batch([twins[i] for i in pair], [seeds(3)[i] for i in pair], wave=1)
    assert_same(numbers(one_by_one), [single[i] for i in pair])


def test_a_bad_dataset_is_returned_in_its_place(twins, single):
    from handeye_jax import InputError

    twice = snake_grid_px()[[0, 0, 1, 2, 3, 4, 5, 6, 7]]  # landmark 0 twice: refused
    few = synthesize_dataset(draw_truth(7).htm(), draw_truth(7).rig(), twice,
                             22.5 * np.arange(9)).replace(name="twice")  # fmt: skip
    out = calibrate_batch([twins[0], few], seeds(2), errors="return")
    assert isinstance(out[1], InputError)
    assert_same(numbers(out[:1]), single[:1])
    with pytest.raises(InputError):
        calibrate_batch([twins[0], few], seeds(2))


# -- several devices, several processes -------------------------------------------------------

_WORKER = """
import json, os, sys
import jax
{init}
jax.config.update("jax_compilation_cache_dir", os.environ["HANDEYE_JAX_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
from handeye_jax import calibrate_batch, store_programs
store_programs(os.path.join(os.environ["HANDEYE_JAX_CACHE_DIR"], "programs"))
from tests.test_batch import SHARED, batch_twins, numbers, seeds
twins, each = batch_twins(), seeds(3)
out = calibrate_batch([twins[i] for i in SHARED], [each[i] for i in SHARED])
print("DEVICES", jax.device_count(), jax.process_count())
print("RESULT", json.dumps(numbers(out)))
"""

_INIT = """
jax.config.update("jax_platforms", "cpu")
jax.distributed.initialize("127.0.0.1:{port}", num_processes=2, process_id={pid})
"""


def _env(devices: int = 1) -> dict:
    """This process's environment (its XLA flags: the programs compiled here are found in the
    cache), with ``devices`` host devices."""
    flags = os.environ.get("XLA_FLAGS", "")
    if devices > 1:
        flags = f"{flags} --xla_force_host_platform_device_count={devices}".strip()
    return {**os.environ, "PYTHONPATH": str(ROOT), "XLA_FLAGS": flags}


def _parse(stdout: str) -> tuple[list[int], list[dict]]:
    lines = dict(line.split(" ", 1) for line in stdout.splitlines()
                 if line.startswith(("DEVICES ", "RESULT ")))  # fmt: skip
    return [int(x) for x in lines["DEVICES"].split()], json.loads(lines["RESULT"])


def test_two_host_devices_give_the_one_device_run(single):
    code = _WORKER.format(init="")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          env=_env(devices=2),
                          timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    devices, got = _parse(done.stdout)
    assert devices == [2, 1]
    assert_same(got, [single[i] for i in SHARED])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_two_processes_give_the_single_device_run(single):
    port = _free_port()
    procs = [subprocess.Popen([sys.executable, "-c",
                               _WORKER.format(init=_INIT.format(port=port, pid=pid))],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env=_env())  # fmt: skip
             for pid in range(2)]  # fmt: skip
    outs = []
    try:
        for p in procs:
            outs.append(p.communicate(timeout=600))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    for p, (_, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-3000:]
    for out, _ in outs:  # every process returns every result, the other's read back
        devices, got = _parse(out)
        assert devices == [2, 2]
        assert_same(got, [single[i] for i in SHARED])


# -- the command line ---------------------------------------------------------------------------


def test_the_command_fits_a_folder_and_skips_a_bad_dataset_by_name(twins, single, tmp_path,
                                                                  capsys):  # fmt: skip
    from handeye_jax import load_result
    from handeye_jax.cli import main
    from handeye_jax.data import dataset_to_toml

    folder = tmp_path / "fleet"
    folder.mkdir()
    for d in (twins[0], twins[2]):
        (folder / f"{d.name}.toml").write_text(dataset_to_toml(d))
    bad = dataset_to_toml(twins[0]).replace("depth = ", "depth = -", 1)
    (folder / "bad.toml").write_text(bad)
    out = tmp_path / "results"
    code = main(["calibrate-batch", str(folder), "--out", str(out), "--population", "48",
                 "--generations", "60", "--restarts", "4", "--quiet"])  # fmt: skip
    said = capsys.readouterr()
    assert code == 2  # one dataset skipped
    skipped = [line for line in said.err.splitlines() if "bad.toml" in line]
    assert len(skipped) == 1 and "skipped" in skipped[0] and "depth" in skipped[0]
    assert sorted(p.name for p in out.iterdir()) == ["summary.csv", "twin3.result.json",
                                                     "twin6.result.json"]  # fmt: skip
    first = load_result(out / "twin3.result.json")
    assert abs(first.stage1.F - single[0]["F1"]) <= 1e-9  # seed 1, as calibrate --seed 1
    assert abs(first.stage2.F - single[0]["F2"]) <= 1e-9
    table = said.out.splitlines()
    assert table[0].split() == ["dataset", "rows", "F1_mm", "F2_mm", "time_s", "result"]
    assert any("bad.toml" in line and "skipped" in line for line in table)
    assert "2 of 3 datasets calibrated" in said.out
    rows = (out / "summary.csv").read_text().splitlines()
    assert len(rows) == 4 and rows[0] == "dataset,rows,F1_mm,F2_mm,time_s,result"


def test_the_command_refuses_a_pattern_that_matches_nothing(tmp_path, capsys):
    from handeye_jax.cli import main

    code = main(["calibrate-batch", str(tmp_path / "*.toml"), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "no dataset files" in err
    assert not (tmp_path / "r").exists()


def test_the_command_refuses_processes_without_a_coordinator_in_one_line(tmp_path, capsys):
    from handeye_jax.cli import main

    code = main(["calibrate-batch", str(tmp_path), "--out", str(tmp_path / "r"),
                 "--processes", "2"])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--processes" in err
    assert "--coordinator" in err and not (tmp_path / "r").exists()


def test_a_folder_of_bad_datasets_writes_only_the_summary(twins, tmp_path, capsys):
    from handeye_jax.cli import main
    from handeye_jax.data import dataset_to_toml

    (tmp_path / "bad.toml").write_text(dataset_to_toml(twins[0]).replace("depth = ", "depth = -"))
    out = tmp_path / "results"
    assert main(["calibrate-batch", str(tmp_path), "--out", str(out), "--quiet"]) == 2
    said = capsys.readouterr()
    assert "0 of 1 datasets calibrated" in said.out
    assert [p.name for p in out.iterdir()] == ["summary.csv"]
