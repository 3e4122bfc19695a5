"""The convergence benchmark runs at its tiny size, prints a row per method and plots. No timing."""

import re
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "convergence.py"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def test_convergence_quick_prints_every_method_and_plots(tmp_path):
    p = subprocess.run(
        [sys.executable, str(SCRIPT), "--quick", "--out-dir", str(tmp_path)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr[-3000:]
    out = p.stdout
    for method in (r"DE alone, calibrate defaults", r"DE \d+ gen \+ LM", "multi-start LM",
                   "multi-start BFGS"):  # fmt: skip
        # A summary row: method, seeds reaching the target as "i/S", then four more cells.
        assert re.search(rf"^\| {method}[^|]* \| \d+/\d+ \|( [^|]+ \|){{4}}$", out, re.M), method
    png = tmp_path / "convergence.png"
    assert png.exists()
    data = png.read_bytes()
    assert data[:8] == PNG_SIGNATURE and len(data) > 8
    assert (tmp_path / "convergence.svg").exists()
