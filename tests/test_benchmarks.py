"""Every benchmark runs at a tiny size, so none can rot. No timing is asserted."""

import contextlib
import io
import re
import runpy
import subprocess
import sys
from pathlib import Path
from unittest import mock

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _run(script, *args):
    """``python benchmarks/SCRIPT ARGS`` in a fresh process: for the benchmarks that need one
    (first_call times fresh processes; de_overhead sets XLA's flags before JAX starts)."""
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


def test_miss_rate_finds_main_missing_twin_1_and_the_new_defaults_not():
    out = run_in_process("miss_rate.py", "--quick")
    assert "| main's defaults (no restarts) | 1 of 1 | 1 |" in out
    assert "| new defaults (restarts 32 + refits) | 0 of 1 | - |" in out


@pytest.mark.parametrize("seeds", [["--seeds", "1"]])
def test_reproduce_paper_runs(seeds):
    out = run_in_process("reproduce_paper.py", *seeds, "--population", "60", "--generations", "80")
    assert out.count("| seed 1 |") == 3


def test_first_call_reports_cold_and_warm():
    out = _run("first_call.py", "--quick", "--no-diagnostics")
    assert "| cold |" in out and "| warm |" in out
    # the per-program table parsed JAX's compile log: the DE loop and the LM polish are in it
    assert "| _chunk_scan | 2 |" in out and "| _lm | 2 |" in out and "| all |" in out


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
    assert re.search(r"NumPy Predictor, in this process: \d+\.\d+ µs per point", out)
