"""Every benchmark runs at a tiny size, so none can rot. No timing is asserted."""

import contextlib
import io
import json
import re
import runpy
import subprocess
import sys
from pathlib import Path
from unittest import mock

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # subprocesses and whole scripts

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _run(script, *args):
    """``python benchmarks/SCRIPT ARGS`` in a fresh process: for the benchmarks that need one
    (startup times fresh processes; de_overhead sets XLA's flags before JAX starts)."""
    p = subprocess.run([sys.executable, str(BENCH / script), *args], capture_output=True,
                       text=True, timeout=600)  # fmt: skip
    assert p.returncode == 0, p.stderr[-3000:]
    return p.stdout


def run_in_process(script, *args):
    """What ``python benchmarks/SCRIPT ARGS`` prints, run in this process: it reuses the
    suite's imports and compiled programs, where a fresh process would pay for JAX's import
    and every compilation again."""
    out = io.StringIO()
    with mock.patch.object(sys, "argv", [str(BENCH / script), *args]), \
            contextlib.redirect_stdout(out):  # fmt: skip
        runpy.run_path(str(BENCH / script), run_name="__main__")
    return out.getvalue()


def test_de_throughput_runs_all_three_des():
    out = run_in_process("de_throughput.py", "--quick")
    for name in ("handeye-jax", "scipy", "evosax", "objective alone", "full budget", "memory"):
        assert name in out
    # the objective alone, timed in each layout, with the DE's overhead against each
    for layout in ("rows", "columns", "transposed copy"):
        assert re.search(rf"^\| {layout} \| \d+\.\d+ \| -?\d+ % \|$", out, re.M)


def test_scaling_runs_and_plots(tmp_path):
    out = run_in_process("scaling.py", "--quick", "--out-dir", str(tmp_path))
    assert "| 50 |" in out and "| 16 |" in out
    # a whole calibration of 9 landmarks, in its own process: its times and peak memory
    assert re.search(r"^\| 9 \| \d+\.\d\d \| \d+\.\d\d \| \d+\.\d\d \| [\d.]+ \| [\d.]+ \| \d+ \|$",
                     out, re.M)  # fmt: skip
    for name in ("scaling.png", "scaling_calibration.png"):
        png = (tmp_path / name).read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_miss_rate_finds_de_and_lm_missing_twin_1_and_the_defaults_not():
    out = run_in_process("miss_rate.py", "--quick")
    assert "| DE + LM (restarts 0) | 1 of 1 | 1 |" in out
    assert "| defaults (restarts 32 + refits) | 0 of 1 | - |" in out
    assert "| defaults, then diagnose | 0 of 1 | - |" in out
    assert "parameters they changed (bit for bit): on no twin" in out


@pytest.mark.parametrize("seeds", [["--seeds", "1"]])
def test_reproduce_paper_runs(seeds):
    # The suite's population (tests/common.py), so the DE's programs are the paper fits' own.
    out = run_in_process("reproduce_paper.py", *seeds, "--population", "200", "--generations", "80")
    assert out.count("| seed 1 |") == 5  # 3 in the paper's ranges, 2 with the default search
    assert "## DH, default search" in out


def test_moved_paper_runs_both_moves_models_and_presets():
    out = run_in_process("moved_paper.py", "--quick")
    for row in ("| shifted +300 mm in x | HTM | estimate |", "| turned 90° about z | DH | paper |"):
        assert row in out


def test_wide_rigs_runs_and_counts_its_rigs():
    out = run_in_process("wide_rigs.py", "--quick")
    assert re.search(r"^\| all \| all \| 2 \| \d \| \d \|", out, re.M)


def test_de_overhead_times_every_ablation_and_reads_xla_ir():
    out = _run("de_overhead.py", "--quick", "--vectors")
    names = ("as shipped", "x·(1+ε) trial", "fixed donors", "crossover draws only",
             "no random gather", "objective alone")  # fmt: skip
    for name in names:
        assert f"| {name} |" in out
    # the vector report read the DE loop's fusions from XLA's dump, population-shaped ones too
    assert re.search(r"^\| \S+ \| f64\[64,12\]\S* \| \d+ \|$", out, re.M)
    assert re.search(r"\d+ of these \d+ fusions are scalar code", out)


def test_robust_flags_the_touched_landmark():
    out = run_in_process("robust.py", "--quick")
    rows = [line for line in out.splitlines() if line.startswith(("| l1 |", "| cauchy |"))]
    assert len(rows) == 2
    # landmark 6 was touched 5 mm off: both losses flag it, and only it
    assert all(row.split(" | ")[2] == "[6]" for row in rows), rows


def test_recalibration_benchmark_tables_every_fit():
    out = run_in_process("recalibration.py", "--quick")

    def row(label, k):
        line = next(x for x in out.splitlines() if x.startswith(f"| {label} | {k} |"))
        return [float(v) for v in line.split("|")[3:5]]  # stage 1 and stage 2, mm

    old, full = row("old result unchanged", 0), row("from scratch", 9)
    prior, fix = row("recalibrate --refit pen", 4), row("recalibrate --refit pen --fix", 4)
    # The pen moved 3-15 mm: the old result misses by millimetres, a recalibration does not.
    assert min(old) > 2.0 and max(full + prior + fix) < 1.0
    assert re.search(r"^\| 4 \| \d\.\d{3} \| \d+\.\d, \d+\.\d \| [01] of 1 \|", out, re.M)


def test_stage_choice_tables_the_recorded_twins_and_writes_only_where_told(tmp_path):
    """The committed coverage rows (no calibration): the table of the deployed stage against
    the better one, with the rows and the table written where asked, nowhere else."""
    committed = BENCH / "results" / "stage_choice.json"
    before = committed.read_bytes()
    out, md = tmp_path / "rows.json", tmp_path / "results.md"
    text = run_in_process("stage_choice.py", "--seeds", "2", "--rows",
                          str(BENCH / "results" / "coverage.json"), "--out", str(out),
                          "--results", str(md))  # fmt: skip
    assert committed.read_bytes() == before
    rows = json.loads(out.read_text())
    twins = sorted((r["model"], r["captures"], r["seed"]) for r in rows)
    assert twins == sorted((m, c, s) for m in ("dh", "htm") for c in (1, 3) for s in (1, 2))
    ratio = float(re.search(r"^8 twins; .* is (\d\.\d{3})× the better", text, re.M).group(1))
    want = np.mean([r["deployed_mm"] for r in rows]) / np.mean([r["better_mm"] for r in rows])
    assert ratio == round(want, 3) and f"rows in {out}" in text
    assert md.read_text().count("| all | 8 |") == 1


def test_partial_match_reads_no_picture_wrong():
    out = run_in_process("partial_match.py", "--trials", "40", "--seed", "3")
    total = [line.split() for line in out.splitlines() if line.strip().startswith("total")]
    assert len(total) == 1
    right, refused, _, avoidable, wrong = map(int, total[0][1:6])
    assert wrong == 0 and right + refused == 40 and right > 20
    # blobs that span a quadrilateral are never refused as collinear, nor as matching nothing
    assert avoidable == 0 and total[0][6:8] == ["(0,", "0,"], out


def test_dots_by_height_finds_two_pixel_dots_from_80_mm_higher():
    out = run_in_process("dots_by_height.py", "--seeds", "1", "1", "--rises", "80", "--dots", "2")
    rows = [line for line in out.splitlines() if line.startswith("| 2 | 80 |")]
    assert len(rows) == 1 and "| 1 of 1 |" in rows[0], out


def test_multicapture_runs_recovers_noise_free_twins_and_plots(tmp_path):
    """Issue 18's acceptance at a tiny size: noise-free three-capture twins (HTM on the twin,
    DH on its own truth) recovered to F < 1e-6 mm with x-y and z commands to 1e-6 mm from a
    capture pose no fit used; one paper-noise twin scored by capture and target height."""
    fig = tmp_path / "multicapture.png"
    out = run_in_process("multicapture.py", "--quick", "--figure", str(fig))
    rows = re.findall(r"^\| (HTM twin seed 1|DH, its own truth) \| 90, -1 \| (\S+) \| (\S+) \| "
                      r"(\S+) \| (\S+) \|$", out, re.M)  # fmt: skip
    assert len(rows) == 2, out
    for _, *numbers in rows:
        assert all(float(x) < 1e-6 for x in numbers), rows
    for group in ("60 mm higher (new pose), on the display", "all targets 50 mm above"):
        assert re.search(rf"^\| {re.escape(group)}[^|]* \|( \d+\.\d{{3}} \|){{7}}$", out, re.M)
    png = fig.read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_startup_times_every_command_and_the_parts_of_a_calibration():
    out = run_in_process("startup.py", "--quick")
    for row in ("calibrate cold", "calibrate warm", "predict", "handeye-jax --help",
                "calibrate --help", "export --help", "detect --help"):  # fmt: skip
        assert re.search(rf"^\| {row} \| \d+\.\d\d \[\d+\.\d\d, \d+\.\d\d\] \| [\d.]+ \|$",
                         out, re.M), row  # fmt: skip
    # the instrumented runs: each stage with its tracing, lowering and compilation, cold and warm
    for kind in ("cold", "warm"):
        for part in ("import", "stage1_de", "stage1_polish", "stage2_polish", "whole process"):
            assert re.search(rf"^\| {kind} \| {part} \| \d+\.\d\d \| ", out, re.M), (kind, part)
    # the cold run's programs: the DE loop and the LM polish of both stages are in it
    assert re.search(r"^\| _de_chunk \| 2 \| ", out, re.M)  # optim/_many's, a batch of one
    assert re.search(r"^\| _polish \| 2 \| ", out, re.M) and "| all |" in out
    assert re.search(r"NumPy Predictor, in this process: \d+\.\d+ µs per point", out)


def test_suite_profile_names_each_compilation_s_test_and_program(tmp_path, monkeypatch):
    probe = tmp_path / "test_probe.py"
    probe.write_text(
        "import jax\n\n"
        "def test_compiles():\n    assert float(jax.jit(lambda x: x * 3.0)(2.0)) == 6.0\n\n"
        "def test_compiles_nothing():\n    assert True\n"
    )
    # In an xdist worker, as the suite runs: the profiled pytest inherits the worker's name, and
    # its own worker (as the suite's, under xdist) takes the same one; each keeps its rows.
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw0")
    out = run_in_process("suite_profile.py", "--top", "5", "--", str(probe), "-n", "1")
    assert re.search(r"; 2 tests, their times summed \d+\.\d s$", out, re.M), out
    assert re.search(r"XLA \d+\.\d s in 1 compilations;", out), out
    assert re.search(r"^\| <lambda> \| \d+\.\d \| 1 \| 0 \|$", out, re.M), out
    tests = out.split("| test | time, s | built, s |")[1]
    # (the test's id starts at pytest's rootdir, which depends on where the clone is)
    assert re.search(r"^\| \S*test_probe\.py::test_compiles \| \d+\.\d \| \d+\.\d \|$", tests,
                     re.M)  # fmt: skip
    assert "test_compiles_nothing" not in tests  # it built nothing


def test_tablet_attack_runs_every_attack():
    out = _run("tablet_attack.py", "--connections", "40", "--seconds", "1", "--drip", "0.5",
               "--resets", "5")  # fmt: skip
    assert re.search(r"40 slow connections, 1 s: operator answered (\d+) of \1,", out), out
    assert re.search(r"5 reset connections: \d log lines", out), out
    assert "control bytes of a request path in the log: False" in out
