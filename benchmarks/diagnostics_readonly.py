"""Diagnostics only read a fit: four ways to calibrate give the same parameters, bit for bit.

    python benchmarks/diagnostics_readonly.py [--twins 10] [--quick]

On the paper's data and on ``--twins`` synthetic ``paper`` twins (seeds 1 to N, as
``handeye-jax simulate DIR --seed S --preset paper`` makes them, each written to a dataset file
first), with the default settings:

* ``calibrate()`` from Python;
* ``handeye-jax calibrate DATASET --out R.json`` (the diagnostics included), a new process;
* the same with ``--no-diagnostics``;
* ``diagnose()`` of the Python result.

Each stage's parameters and F are compared as float64 bit patterns (the result files hold
them as JSON, whose decimal form round-trips exactly). The acceptance of issue 24: identical on
every dataset. The command line uses the XLA cache of ``HANDEYE_JAX_CACHE_DIR`` (as a user's
run does; its first run compiles).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from handeye_jax import (
    PRESETS,
    Settings,
    calibrate,
    diagnose,
    draw_truth,
    load_dataset,
    load_result,
    save_dataset,
    simulate,
    vectorise_small_loops,
)

PAPER = Path(__file__).resolve().parents[1] / "data" / "paper2023.toml"
WAYS = ("calibrate()", "CLI", "CLI --no-diagnostics", "diagnose()")


def fingerprint(result) -> tuple:
    """Each stage's F and parameters, as float64 bit patterns (``float.hex``)."""
    return tuple(
        (float(s.F).hex(), tuple((k, float(v).hex()) for k, v in s.params.items()))
        for s in (result.stage1, result.stage2)
    )


def cli_result(dataset: Path, out: Path, extra: list[str], settings_args: list[str]):
    cmd = [sys.executable, "-m", "handeye_jax.cli", "calibrate", str(dataset), "--quiet",
           "--out", str(out), *settings_args, *extra]  # fmt: skip
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return load_result(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--twins", type=int, default=10, help="paper twins, seeds 1..N (default 10)")
    ap.add_argument("--quick", action="store_true",
                    help="1 twin, a tiny DE (population 40, 30 generations): a smoke test",
                    )  # fmt: skip
    args = ap.parse_args(argv)
    vectorise_small_loops()  # as the command line does
    settings, settings_args = Settings(), []
    if args.quick:
        args.twins = 1
        settings = Settings(population=40, generations=30)
        settings_args = ["--population", "40", "--generations", "30"]

    print(f"# Diagnostics read only, {time.strftime('%Y-%m-%d')}")
    print(f"command: python benchmarks/{Path(__file__).name} {' '.join(sys.argv[1:])}")
    print(f"load average at start {os.getloadavg()[0]:.2f}; the command line's XLA cache: "
          f"{os.environ.get('HANDEYE_JAX_CACHE_DIR', 'the default')}")  # fmt: skip
    print(f"\n| data | F1st mm | {' | '.join(WAYS[1:])} (same as calibrate()?) |")
    print("|---|---|" + "---|" * (len(WAYS) - 1))
    same = 0
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        files = {"paper": PAPER}
        for seed in range(1, args.twins + 1):
            twin = simulate(draw_truth(seed), PRESETS["paper"], seed).dataset
            files[f"twin {seed}"] = tmp / f"twin{seed}.toml"
            save_dataset(twin, files[f"twin {seed}"])
        for name, path in files.items():
            ds = load_dataset(path)
            fitted = calibrate(ds, settings)
            prints = {
                "calibrate()": fingerprint(fitted),
                "CLI": fingerprint(cli_result(path, tmp / "r.json", [], settings_args)),
                "CLI --no-diagnostics": fingerprint(
                    cli_result(path, tmp / "r.json", ["--no-diagnostics"], settings_args)
                ),
                "diagnose()": fingerprint(diagnose(fitted, search=ds.search)),
            }
            agree = [prints[w] == prints["calibrate()"] for w in WAYS[1:]]
            same += all(agree)
            cells = " | ".join("same" if a else "DIFFERENT" for a in agree)
            print(f"| {name} | {fitted.stage1.F:.6f} | {cells} |", flush=True)
    print(f"\nparameters and F of both stages identical in all four ways on {same} of "
          f"{len(files)} datasets; load average at end {os.getloadavg()[0]:.2f}")  # fmt: skip
    return 0 if same == len(files) else 1


if __name__ == "__main__":
    sys.exit(main())
