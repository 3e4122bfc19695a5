"""Where the test suite's time goes: each test's time, and the JAX compilation inside it by
program (the suite's 10-minute budget).

    python benchmarks/suite_profile.py [--warm DIR] [--top N] [-- PYTEST ARGS ...]

Runs ``python -m pytest`` with its arguments as given (default: the whole suite, as the
README's test command runs it) and with this file as a plugin in every test process, the
xdist workers too. The plugin listens to ``jax.monitoring``'s compile events (tracing,
lowering, XLA's compilation, and fetches from the persistent cache), and notes each one's test
and program. The compiled programs go to a new, empty folder (a cold run, as on a fresh
clone) unless ``--warm DIR`` names a folder to reuse. The report gives the totals, the
programs that cost most to build, and the test files and tests that compile most.

Compilation in processes the tests start themselves (the command line's, the notebooks'
kernel) is not seen: it counts only in those tests' time.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
#: The environment variable that turns the plugin on: the folder it writes its rows to.
OUT_ENV = "SUITE_PROFILE_DIR"
#: jax.monitoring's duration events, by the phase of building a program they time. On a hit
#: of the persistent cache, JAX reports the fetch (without the program's name), then the
#: backend's event for the fetched program: that one is counted as a fetch, not a compilation.
PHASES = {
    "jaxpr_trace_duration": "trace",
    "jaxpr_to_mlir_module_duration": "lower",
    "backend_compile_duration": "xla",
}
FETCH_EVENT = "cache_retrieval_time_sec"
BUILD = ("trace", "lower", "xla", "fetch")

# -- the plugin (imported by pytest in each test process: ``-p suite_profile``) ------------

_rows: list[list] = []
_test = ["(collection)"]
_fetched = [False]  # the next backend event is a cache fetch


def _program(name: str) -> str:
    return name[4:-1] if name.startswith("jit(") and name.endswith(")") else name


def _listen(event: str, duration: float, **kw) -> None:
    name = event.rsplit("/", 1)[-1]
    if name == FETCH_EVENT:
        _fetched[0] = True
        return
    phase = PHASES.get(name)
    if phase == "xla" and _fetched[0]:
        phase, _fetched[0] = "fetch", False
    if phase is not None:
        _rows.append(["build", _test[0], _program(str(kw.get("fun_name", "?"))), phase, duration])


if os.environ.get(OUT_ENV):
    import jax.monitoring

    jax.monitoring.register_event_duration_secs_listener(_listen)


def pytest_runtest_logstart(nodeid, location):
    _test[0] = nodeid


def pytest_runtest_logreport(report):
    # xdist reports each test in its worker and again in the controller: the analysis keeps
    # one row per (test, phase).
    _rows.append(["test", report.nodeid, report.when, report.duration])


def pytest_sessionfinish(session):
    folder = os.environ.get(OUT_ENV)
    if folder:
        # The process id too: a pytest started from inside an xdist worker (as the suite's own
        # test of this file does) inherits that worker's name, which its own workers reuse.
        name = f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')}-{os.getpid()}"
        with open(Path(folder) / f"{name}.jsonl", "w") as f:
            f.writelines(json.dumps(r) + "\n" for r in _rows)


# -- the run and its report ----------------------------------------------------------------


def read_rows(folder: Path) -> tuple[dict, list[list]]:
    """The plugin's rows from every process: each test phase's duration, s (one per test and
    phase), and the build events ``[test, program, phase, seconds]``."""
    durations, builds = {}, []
    for path in sorted(folder.glob("*.jsonl")):
        for line in path.read_text().splitlines():
            row = json.loads(line)
            if row[0] == "test":
                durations[(row[1], row[2])] = row[3]
            else:
                builds.append(row[1:])
    return durations, builds


def report(durations: dict, builds: list[list], wall_s: float, top: int) -> str:
    """The report's text: totals, then tables by program, by test file and by test."""
    C = collections.Counter
    phase_s, phase_n, program_s, compiled, fetched, test_build = C(), C(), C(), C(), C(), C()
    for test, program, phase, s in builds:
        phase_s[phase] += s
        phase_n[phase] += 1
        program_s[program] += s
        test_build[test] += s
        compiled[program] += phase == "xla"
        fetched[program] += phase == "fetch"
    test_s = collections.Counter()
    for (test, _), s in durations.items():
        test_s[test] += s
    file_s, file_build = collections.Counter(), collections.Counter()
    for test, s in test_s.items():
        file_s[test.split("::")[0]] += s
    for test, s in test_build.items():
        file_build[test.split("::")[0]] += s
    summed, built = sum(test_s.values()), sum(phase_s[p] for p in BUILD)
    lines = [
        f"wall time of the pytest run: {wall_s:.1f} s; {len(test_s)} tests, their times summed "
        f"{summed:.1f} s",
        f"built in the test processes: {built:.1f} s ({100 * built / max(summed, 1e-9):.0f} % of "
        f"the summed time): tracing {phase_s['trace']:.1f} s, lowering {phase_s['lower']:.1f} s, "
        f"XLA {phase_s['xla']:.1f} s in {phase_n['xla']} compilations; {phase_n['fetch']} "
        f"programs fetched from the persistent cache in {phase_s['fetch']:.1f} s",
        "",
        "| program | built, s | XLA compilations | fetched |",
        "|---|---|---|---|",
        *(f"| {p} | {s:.1f} | {compiled[p]} | {fetched[p]} |"
          for p, s in program_s.most_common(top)),
        "",
        "| test file | time, s | built, s |",
        "|---|---|---|",
        *(f"| {f} | {s:.1f} | {file_build[f]:.1f} |" for f, s in file_s.most_common(top)),
        "",
        "| test | time, s | built, s |",
        "|---|---|---|",
        *(f"| {t} | {test_s[t]:.1f} | {s:.1f} |" for t, s in test_build.most_common(top)),
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--warm", metavar="DIR", help="reuse this folder of compiled programs")
    ap.add_argument("--top", type=int, default=15, help="rows per table (default 15)")
    ap.add_argument("pytest_args", nargs=argparse.REMAINDER,
                    help="pytest's arguments, after --")  # fmt: skip
    args = ap.parse_args(argv)
    pytest_args = args.pytest_args[1:] if args.pytest_args[:1] == ["--"] else args.pytest_args
    with tempfile.TemporaryDirectory(prefix="suite-profile-") as tmp:
        out = Path(tmp) / "rows"
        out.mkdir()
        path = os.pathsep.join(p for p in (str(BENCH), os.environ.get("PYTHONPATH")) if p)
        env = {**os.environ, OUT_ENV: str(out), "PYTHONPATH": path,
               "HANDEYE_JAX_CACHE_DIR": args.warm or str(Path(tmp) / "xla")}  # fmt: skip
        t0 = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "suite_profile",
                               *pytest_args], cwd=ROOT, env=env)  # fmt: skip
        wall = time.perf_counter() - t0
        durations, builds = read_rows(out)
    print(f"# The suite's time by compiled program\ncommand: python benchmarks/suite_profile.py "
          f"{' '.join(argv if argv is not None else sys.argv[1:])}\n")  # fmt: skip
    print(report(durations, builds, wall, args.top))
    if done.returncode:
        print(f"\npytest exited with {done.returncode}", file=sys.stderr)
    return done.returncode


if __name__ == "__main__":
    if code := main():
        sys.exit(code)
