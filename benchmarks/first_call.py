"""Where the time of ``handeye-jax calibrate data/paper2023.toml`` goes, from the shell.

    python benchmarks/first_call.py [--runs 3] [--quick]

Runs the command as a user would, in fresh processes: once with an empty XLA compilation
cache ("cold": the very first run on a machine) and then with the cache the first run left
("warm": every later run). Reports the wall time and its parts: Python and JAX import, each
stage's DE and LM and the diagnostics (compilation included, as the result's timings record
them), and the rest. Then, from one more cold run with ``JAX_LOG_COMPILES=1``, the time JAX
logs for tracing, lowering to MLIR and XLA compilation, per compiled program.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMPORT = (  # what calibrate imports (the command line itself imports them on use)
    "import time; t = time.perf_counter(); import handeye_jax.cli, "
    "handeye_jax.calibration._calibrate, handeye_jax.data._dataset_io, "
    "handeye_jax.calibration._result_io; print(time.perf_counter() - t)"
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


PHASES = {"tracing": "tracing", "jaxpr to MLIR module conversion": "lowering",
          "XLA compilation": "compilation"}  # fmt: skip
LOGGED = re.compile(
    r"Finished (tracing|jaxpr to MLIR module conversion|XLA compilation) (?:of |for )?"
    r"(?:jit\()?([^\s)]+)\)?.* in ([0-9.e+-]+) sec"
)


def programs(extra: list[str]) -> dict[str, dict[str, float]]:
    """Seconds of tracing, lowering and compilation per program in one cold run."""
    env = dict(os.environ, JAX_LOG_COMPILES="1")
    with tempfile.TemporaryDirectory() as tmp:
        env["HANDEYE_JAX_CACHE_DIR"] = tmp
        cmd = ["handeye-jax", "calibrate", str(ROOT / "data" / "paper2023.toml"), "--quiet",
               "--out", str(Path(tmp) / "r.json"), *extra]  # fmt: skip
        log = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stderr
    rows: dict[str, dict[str, float]] = collections.defaultdict(lambda: dict.fromkeys(
        ["tracing", "lowering", "compilation", "compiled"], 0.0))  # fmt: skip
    for phase, name, seconds in LOGGED.findall(log):
        rows[name][PHASES[phase]] += float(seconds)
        rows[name]["compiled"] += phase == "XLA compilation"
    return dict(rows)


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

    rows = programs(extra)
    print("\none more cold run, JAX_LOG_COMPILES=1: seconds per program (tracing includes the")
    print("tracing of nested functions; programs compiled more than once are summed)\n")
    print("| program | compiled | tracing | lowering | XLA compilation |")
    print("|---|---|---|---|---|")
    order = sorted(rows, key=lambda k: -sum(v for p, v in rows[k].items() if p != "compiled"))
    for name in order:
        r = rows[name]
        print(f"| {name} | {int(r['compiled'])} | {r['tracing']:.2f} | {r['lowering']:.2f} | "
              f"{r['compilation']:.2f} |")  # fmt: skip
    total = {p: sum(r[p] for r in rows.values()) for p in ("compiled", *PHASES.values())}
    print(f"| all | {int(total['compiled'])} | {total['tracing']:.2f} | {total['lowering']:.2f} | "
          f"{total['compilation']:.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
