"""How quickly the command line answers (issue 19, section 3), before and after, side by side.

    python benchmarks/startup.py [--runs 5] [--before /work/main] [--quick]

Every figure but the predictor's is the wall time of a fresh process, median of ``--runs``:

* ``predict RESULT.json POINTS.csv`` on a 2-point CSV (target 1.0 s);
* ``--help`` of the command line and of every subcommand (target 0.5 s);
* ``calibrate data/paper2023.toml`` (diagnostics included) with an empty compilation cache
  ("cold", target 12 s) and with the cache the cold run left ("warm", target 6 s).

``--before TREE`` runs the same commands on another source tree (e.g. the main checkout) in
turn with this one, so that the machine's drift hits both alike and their ratio holds.

The cold and warm ``calibrate`` runs are instrumented in their own processes, to say where
the seconds go: the import, each stage's DE and LM polish, the diagnostics and the output; in
each, the seconds JAX spent tracing, lowering to MLIR and compiling (or fetching from the
cache) and the number of programs, from ``jax.monitoring``'s events. What is left is
computation and Python. For the cold run, the same per program (as JAX names it: a
``multiply`` is one operation run on its own, outside any compiled program).

Last, in this process, the NumPy ``Predictor`` on 10,000 points (target 20 µs per point).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "data" / "paper2023.toml"
SUBCOMMANDS = ("calibrate", "predict", "report", "tablet", "simulate", "detect", "evaluate",
               "export")  # fmt: skip
#: ``--quick`` times the help of these only (the three tests/test_benchmarks.py reads).
QUICK_SUBCOMMANDS = ("calibrate", "export", "detect")
POINTS_CSV = "u,v,depth,hand_angle\n338,244,169.2,90\n119,105,168.2,0\n"
TARGETS_S = {"predict": 1.0, "help": 0.5, "calibrate cold": 12.0, "calibrate warm": 6.0}
PREDICTOR_TARGET_US = 20.0
PARTS = ("import", "stage1_de", "stage1_polish", "stage2_de", "stage2_polish", "diagnostics",
         "output")  # fmt: skip
EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "tracing",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lowering",
    "/jax/core/compile/backend_compile_duration": "compiling",
}

# The instrumented run, in its own process (``python -c DRIVER OUT.json ARGS``).
DRIVER = r"""
import json, os, sys, time
t0 = time.perf_counter()
import handeye_jax.cli as cli
import jax, jax.monitoring
import handeye_jax.calibration._batch as cal
import handeye_jax.diagnostics as diagnostics
t_import = time.perf_counter() - t0
events = []  # (end time, kind, seconds, program)
jax.monitoring.register_event_duration_secs_listener(
    lambda name, secs, **kw: events.append((time.perf_counter(), name, secs,
                                            str(kw.get("fun_name", "?")))))
spans = []  # (label, start, end)
fit_stages, diagnose = cal.fit_stages, diagnostics.diagnose
def timed_fit_stages(*args, **kwargs):
    start = time.perf_counter()
    fits = fit_stages(*args, **kwargs)
    fit = fits[0]
    end = time.perf_counter()
    stage = "stage2" if len([s for s in spans if s[0].endswith("_de")]) else "stage1"
    spans.extend([(f"{stage}_de", start, end - fit.timings["polish"]),
                  (f"{stage}_polish", end - fit.timings["polish"], end)])
    return fits
def timed_diagnose(*args, **kwargs):
    start = time.perf_counter()
    out = diagnose(*args, **kwargs)
    spans.append(("diagnostics", start, time.perf_counter()))
    return out
cal.fit_stages, diagnostics.diagnose = timed_fit_stages, timed_diagnose
t1 = time.perf_counter()
code = cli.main(sys.argv[2:])
t_end = time.perf_counter()
assert code == 0, code
spans.insert(0, ("import", t0, t1))
spans.append(("output", spans[-1][2], t_end))
parts = {}
for label, a, b in spans:
    part = {"wall": (b - a) if label != "import" else t_import, "programs": 0,
            "tracing": 0.0, "lowering": 0.0, "compiling": 0.0}
    for t, name, secs, _ in events:
        if a < t <= b and name in EVENTS:
            part[EVENTS[name]] += secs
            part["programs"] += EVENTS[name] == "compiling"
    parts[label] = part
programs = {}  # per program, as JAX names it: its seconds of each kind, and compilations
for _, name, secs, fun in events:
    fun = fun[4:-1] if fun.startswith("jit(") else fun  # tracing names it without jit(...)
    if name in EVENTS:
        row = programs.setdefault(fun, {"tracing": 0.0, "lowering": 0.0, "compiling": 0.0,
                                        "compiled": 0})
        row[EVENTS[name]] += secs
        row["compiled"] += EVENTS[name] == "compiling"
parts["programs"] = programs
json.dump(parts, open(sys.argv[1], "w"))
sys.stdout.flush()
os._exit(0)  # as the console script does (handeye_jax.cli.run): no teardown of XLA
"""


def _env(tree: Path, cache: str | None = None) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    if cache is not None:
        env["HANDEYE_JAX_CACHE_DIR"] = cache
    return env


def _wall(cmd: list[str], env: dict[str, str]) -> float:
    # In the tree measured: ``python -m`` and ``-c`` put the working folder first on the path.
    cwd = env["PYTHONPATH"]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900, cwd=cwd)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:4])}...: exit {p.returncode}: {p.stderr[-2000:]}")
    return wall


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "handeye_jax.cli", *args]


def _calibrate_parts(tree: Path, cache: str, extra: list[str], tmp: Path) -> dict:
    """One instrumented ``calibrate``: its process wall time and its parts (``DRIVER``)."""
    report = tmp / "parts.json"
    driver = f"EVENTS = {EVENTS!r}\n{DRIVER}"
    cmd = [sys.executable, "-c", driver, str(report), "calibrate", str(PAPER), "--quiet",
           "--out", str(tmp / "result.json"), *extra]  # fmt: skip
    wall = _wall(cmd, _env(tree, cache))
    return {"wall": wall, **json.loads(report.read_text())}


def measure(trees: dict[str, Path], runs: int, extra: list[str], tmp: Path,
            subcommands: tuple[str, ...] = SUBCOMMANDS):  # fmt: skip
    """Wall times, s, ``{tree: {what: [run, ...]}}``, and the instrumented calibrations'
    parts, ``{tree: {kind: [parts, ...]}}``; the trees in turn within each run. The ``--help``
    of the command line and of each of ``subcommands``."""
    walls: dict[str, dict[str, list[float]]] = {name: {} for name in trees}
    parts: dict[str, dict[str, list[dict]]] = {name: {"cold": [], "warm": []} for name in trees}
    points = tmp / "points.csv"
    points.write_text(POINTS_CSV)
    for run in range(runs):
        for name, tree in trees.items():
            w = walls[name]
            with tempfile.TemporaryDirectory(dir=tmp) as cache:
                for kind in ("cold", "warm"):
                    p = _calibrate_parts(tree, cache, extra, tmp)
                    parts[name][kind].append(p)
                    w.setdefault(f"calibrate {kind}", []).append(p["wall"])
                result = tmp / f"{name}.result.json"
                (tmp / "result.json").replace(result)
                wall = _wall(_cli("predict", str(result), str(points)), _env(tree, cache))
                w.setdefault("predict", []).append(wall)
            for sub in ("", *subcommands):
                cmd = _cli(*([sub] if sub else []), "--help")
                w.setdefault(f"{sub or 'handeye-jax'} --help", []).append(_wall(cmd, _env(tree)))
        print(f"run {run + 1} of {runs} done", file=sys.stderr)
    return walls, parts


def predictor_us(result: Path, n: int, rounds: int) -> float:
    """Median µs per point of ``Predictor.hand_command`` on ``n`` random points, in-process."""
    import numpy as np

    from handeye_jax import Predictor

    predictor = Predictor.from_result(result)
    rng = np.random.default_rng(0)
    uv = rng.uniform([0.0, 0.0], [640.0, 480.0], (n, 2))
    depth, angle = rng.uniform(150.0, 190.0, n), rng.uniform(-180.0, 180.0, n)
    predictor.hand_command(uv, depth, angle)
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        predictor.hand_command(uv, depth, angle)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) / n * 1e6


def _table(walls: dict[str, dict[str, list[float]]]) -> None:
    names = list(walls)
    ratio = len(names) == 2
    head = " | ".join(f"{n}: median [min, max]" for n in names)
    print(f"| command | {head} | target |{' after / before |' if ratio else ''}")
    print("|---" * (len(names) + 2 + ratio) + "|")
    for row in walls[names[0]]:
        cells = []
        for n in names:
            v = walls[n][row]
            cells.append(f"{statistics.median(v):.2f} [{min(v):.2f}, {max(v):.2f}]")
        target = TARGETS_S["help" if "--help" in row else row]
        line = f"| {row} | {' | '.join(cells)} | {target:g} |"
        if ratio:
            before, after = (statistics.median(walls[n][row]) for n in names)
            line += f" {after / before:.2f} |"
        print(line)


def _programs_table(name: str, cold: list[dict]) -> None:
    """The cold runs' seconds per program (median over the runs), the largest first."""
    rows = cold[0]["programs"]
    keys = ("tracing", "lowering", "compiling", "compiled")
    med = {fun: {k: statistics.median(r["programs"].get(fun, {}).get(k, 0) for r in cold)
                 for k in keys} for fun in rows}  # fmt: skip
    print(f"\n{name}, cold: seconds per program, median over the runs\n")
    print("| program | compiled | tracing | lowering | compiling |")
    print("|---|---|---|---|---|")
    order = sorted(med, key=lambda f: -(med[f]["tracing"] + med[f]["lowering"]
                                        + med[f]["compiling"]))  # fmt: skip
    for fun in order:
        m = med[fun]
        print(f"| {fun} | {m['compiled']:.0f} | {m['tracing']:.2f} | {m['lowering']:.2f} | "
              f"{m['compiling']:.2f} |")  # fmt: skip
    total = {k: sum(m[k] for m in med.values()) for k in keys}
    print(f"| all | {total['compiled']:.0f} | {total['tracing']:.2f} | {total['lowering']:.2f} "
          f"| {total['compiling']:.2f} |")  # fmt: skip


def _parts_table(name: str, runs: dict[str, list[dict]]) -> None:
    print(f"\n{name}: seconds per part of the instrumented calibrations, median over the runs "
          "(compiling: XLA's compilation, or on a cache hit its fetch; rest: computation and "
          "Python; programs: compiled or fetched)\n")  # fmt: skip
    print("| run | part | wall | tracing | lowering | compiling | rest | programs |")
    print("|---|---|---|---|---|---|---|---|")
    keys = ("wall", "tracing", "lowering", "compiling", "programs")
    for kind, ps in runs.items():
        total = dict.fromkeys(keys[1:], 0.0)
        for part in PARTS:
            if part not in ps[0]:
                continue
            f = {k: statistics.median(p[part][k] for p in ps) for k in keys}
            rest = f["wall"] - f["tracing"] - f["lowering"] - f["compiling"]
            for k in total:
                total[k] += f[k]
            print(f"| {kind} | {part} | {f['wall']:.2f} | {f['tracing']:.2f} | "
                  f"{f['lowering']:.2f} | {f['compiling']:.2f} | {rest:.2f} | "
                  f"{f['programs']:.0f} |")  # fmt: skip
        wall = statistics.median(p["wall"] for p in ps)
        print(f"| {kind} | whole process | {wall:.2f} | {total['tracing']:.2f} | "
              f"{total['lowering']:.2f} | {total['compiling']:.2f} | | "
              f"{total['programs']:.0f} |")  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="fresh processes per figure")
    ap.add_argument("--before", type=Path, help="another source tree to run beside this one")
    ap.add_argument("--quick", action="store_true",
                    help="1 run, tiny DE, no diagnostics, the help of 3 subcommands, 1000 points "
                         "(a smoke test)")  # fmt: skip
    args = ap.parse_args(argv)
    runs = 1 if args.quick else args.runs
    extra = ["--population", "40", "--generations", "20", "--no-diagnostics"] if args.quick else []
    trees = {"after": ROOT}
    if args.before is not None:
        trees = {"before": args.before.resolve(), "after": ROOT}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subcommands = QUICK_SUBCOMMANDS if args.quick else SUBCOMMANDS
        walls, parts = measure(trees, runs, extra, tmp, subcommands)
        n = 1000 if args.quick else 10_000
        us = predictor_us(tmp / "after.result.json", n, 5 if args.quick else 50)

    print(f"# Startup and first call, {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores")
    print(f"command: python benchmarks/{Path(__file__).name} {' '.join(sys.argv[1:])}")
    print(
        f"wall time of fresh processes, s, median [min, max] of {runs}; "
        f"{', '.join(f'{k} = {v}' for k, v in trees.items())}\n"
    )
    _table(walls)
    for name, p in parts.items():
        _parts_table(name, p)
        _programs_table(name, p["cold"])
    print(
        f"\nNumPy Predictor, in this process: {us:.3f} µs per point for {n} points "
        f"(target {PREDICTOR_TARGET_US:g} µs; {us / PREDICTOR_TARGET_US:.4f} of it)"
    )


if __name__ == "__main__":
    main()
