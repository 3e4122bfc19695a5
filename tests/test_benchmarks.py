"""Every benchmark runs at a tiny size, so none can rot. No timing is asserted."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _run(script, *args):
    p = subprocess.run([sys.executable, str(BENCH / script), *args], capture_output=True,
                       text=True, timeout=600)  # fmt: skip
    assert p.returncode == 0, p.stderr[-3000:]
    return p.stdout


def test_de_throughput_runs_all_three_des():
    out = _run("de_throughput.py", "--quick")
    for name in ("handeye-jax", "scipy", "evosax", "objective alone", "full budget", "memory"):
        assert name in out
    # the objective alone, timed in each layout, with the DE's overhead against each
    for layout in ("rows", "columns", "transposed copy"):
        assert re.search(rf"^\| {layout} \| \d+\.\d+ \| -?\d+ % \|$", out, re.M)


def test_scaling_runs_and_plots(tmp_path):
    out = _run("scaling.py", "--quick", "--out-dir", str(tmp_path))
    assert "| 50 |" in out and "| 16 |" in out
    png = (tmp_path / "scaling.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


@pytest.mark.parametrize("seeds", [["--seeds", "1"]])
def test_reproduce_paper_runs(seeds):
    out = _run("reproduce_paper.py", *seeds, "--population", "60", "--generations", "80")
    assert out.count("| seed 1 |") == 3


def test_first_call_reports_cold_and_warm():
    out = _run("first_call.py", "--quick")
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
    out = _run("robust.py", "--quick")
    rows = [line for line in out.splitlines() if line.startswith(("| l1 |", "| cauchy |"))]
    assert len(rows) == 2
    # landmark 6 was touched 5 mm off: both losses flag it, and only it
    assert all(row.split(" | ")[2] == "[6]" for row in rows), rows
