"""The convergence benchmark runs at its tiny size, prints a row per method and plots. No timing."""

import re

import pytest

from tests.test_benchmarks import run_in_process

pytestmark = pytest.mark.slow  # subprocesses and whole scripts

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def test_convergence_quick_prints_every_method_and_plots(tmp_path):
    out = run_in_process("convergence.py", "--quick", "--out-dir", str(tmp_path))
    for method in (r"DE alone, calibrate defaults", r"DE \d+ gen \+ LM", "multi-start LM",
                   "multi-start BFGS"):  # fmt: skip
        # A summary row: method, seeds reaching the target as "i/S", then four more cells.
        assert re.search(rf"^\| {method}[^|]* \| \d+/\d+ \|( [^|]+ \|){{4}}$", out, re.M), method
    png = tmp_path / "convergence.png"
    assert png.exists()
    data = png.read_bytes()
    assert data[:8] == PNG_SIGNATURE and len(data) > 8
    assert (tmp_path / "convergence.svg").exists()
