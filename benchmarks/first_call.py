"""Where the time of ``handeye-jax calibrate data/paper2023.toml`` goes, from the shell.

    python benchmarks/first_call.py [--runs 3] [--quick]

Runs the command as a user would, in fresh processes: once with an empty XLA compilation
cache ("cold": the very first run on a machine) and then with the cache the first run left
("warm": every later run). Reports the wall time and its parts: Python and JAX import, each
stage's DE and LM and the diagnostics (compilation included, as the result's timings record
them), and the rest.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMPORT = (
    "import time; t = time.perf_counter(); import handeye_jax.cli; print(time.perf_counter() - t)"
)


STAGES = ("stage1_de", "stage1_polish", "stage2_de", "stage2_polish", "diagnostics")


def run(cache: str, extra: list[str]) -> dict[str, float]:
    env = dict(os.environ, HANDEYE_JAX_CACHE_DIR=cache)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "r.json"
        cmd = ["handeye-jax", "calibrate", str(ROOT / "data" / "paper2023.toml"), "--quiet",
               "--out", str(out), *extra]  # fmt: skip
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, env=env)
        wall = time.perf_counter() - t0
        timings = json.loads(out.read_text())["timings_s"]
    imp = float(subprocess.run([sys.executable, "-c", IMPORT], check=True, capture_output=True,
                               text=True, env=env).stdout)  # fmt: skip
    parts = {k: timings.get(k, 0.0) for k in STAGES}  # no "diagnostics" with --no-diagnostics
    return {"wall": wall, "import": imp, **parts,
            "other": wall - imp - sum(parts.values())}  # fmt: skip


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="cold runs and warm runs each")
    ap.add_argument("--quick", action="store_true", help="one run each, tiny DE (for tests)")
    ap.add_argument("--no-diagnostics", action="store_true", help="pass --no-diagnostics")
    args = ap.parse_args(argv)
    extra = ["--population", "40", "--generations", "20"] if args.quick else []
    extra += ["--no-diagnostics"] if args.no_diagnostics else []
    runs = 1 if args.quick else args.runs
    rows = {"cold": [], "warm": []}
    for _ in range(runs):
        with tempfile.TemporaryDirectory() as cache:
            rows["cold"].append(run(cache, extra))
            rows["warm"].append(run(cache, extra))
    print(f"# first call, {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores")
    print(f"command: python benchmarks/{Path(__file__).name} {' '.join(sys.argv[1:])}")
    print("times in s, median of", runs, "fresh processes each\n")
    keys = ["wall", "import", *STAGES, "other"]
    print("| run | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for name, rs in rows.items():
        med = {k: sorted(r[k] for r in rs)[len(rs) // 2] for k in keys}
        print(f"| {name} | " + " | ".join(f"{med[k]:.2f}" for k in keys) + " |")


if __name__ == "__main__":
    main()
