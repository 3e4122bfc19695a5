"""The suite's shared fixtures: one calibration of the paper's data per run of the suite,
reused by every file that needs a result (``paper_result_file``, ``paper_result``)."""

import os
import signal
import threading
from pathlib import Path

import hypothesis
import jax
import pytest

from handeye_jax import store_programs, vectorise_small_loops

# In-process CLI calls enable XLA's persistent cache; keep it out of the user's home.
os.environ.setdefault(
    "HANDEYE_JAX_CACHE_DIR", str(Path(__file__).resolve().parents[1] / ".pytest_cache" / "xla")
)
# Every test's programs go to that cache from the start, as the command line's do, so a second
# run of the suite loads what the first compiled. (The CLI calls would enable it anyway, but
# only from the first of them on.)
jax.config.update("jax_compilation_cache_dir", os.environ["HANDEYE_JAX_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
# And as the command line runs, from the first test on, in every test process: XLA's flags as
# the command line sets them (they are part of the persistent cache's key, so the suite's
# processes, its command-line subprocesses and the notebooks' kernel share compiled code), and
# the serialized programs beside that cache (a program one process traced, no other traces).
vectorise_small_loops()
store_programs(Path(os.environ["HANDEYE_JAX_CACHE_DIR"]) / "programs")


# Property tests: the same draws on every clone and every run ("ci", the default: derandomised,
# no example database, no verdict by the machine's speed), or new random draws and ten times
# the examples ("explore", run with HYPOTHESIS_PROFILE=explore before an issue is closed; the
# README gives the command).
hypothesis.settings.register_profile(
    "ci", derandomize=True, database=None, print_blob=True, deadline=None,
    suppress_health_check=[hypothesis.HealthCheck.too_slow],
)  # fmt: skip
hypothesis.settings.register_profile("explore", derandomize=False, print_blob=True, deadline=None)
hypothesis.settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
EXPLORE_EXAMPLES = 10  # times each test's own max_examples


def pytest_collection_modifyitems(items):
    """In "explore", each property test runs ten times its own ``max_examples`` (its
    ``@settings`` would otherwise override the profile's)."""
    if hypothesis.settings.get_current_profile_name() != "explore":
        return
    done = set()
    for item in items:
        test = getattr(item, "function", None)
        if not hypothesis.is_hypothesis_test(test) or test in done:
            continue
        done.add(test)
        own = test._hypothesis_internal_use_settings  # where @settings puts them (no public API)
        test._hypothesis_internal_use_settings = hypothesis.settings(
            own, max_examples=own.max_examples * EXPLORE_EXAMPLES
        )


def pytest_sessionfinish(session):
    """A pytest-xdist worker whose tests are done ignores SIGINT. execnet sends one to a worker
    still busy 5 s after the controller ends the run (pytest's closing garbage collections of
    a process holding JAX's programs can take that long), and it lands in whatever runs then:
    hypothesis's gc callback, which printed an "Exception ignored ... KeyboardInterrupt"
    traceback after the last test. (execnet still ends a worker busy 10 s more.)"""
    main = threading.current_thread() is threading.main_thread()  # where handlers are set
    if os.environ.get("PYTEST_XDIST_WORKER") and main:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.fixture(autouse=True)
def _float64():
    """Tests run in float64 the same way users do: scoped, not by flipping global config."""
    with jax.enable_x64(True):
        yield


@pytest.fixture(scope="session")
def paper_result_file(tmp_path_factory) -> Path:
    """The paper's data calibrated as the command line does it (the tests' budget, with
    diagnostics), once per run of the suite: the first worker to need it writes it, the
    others wait for it (pytest-xdist's recipe for a session fixture). Each process gets its
    own copy, in a folder of its own (tests snapshot the folder around the file). Read it; do
    not change it."""
    import shutil

    from filelock import FileLock

    from handeye_jax.cli import main
    from tests.common import FAST, PAPER

    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent  # the folder every worker of this run has its own beside
    done = shared / "paper-session.json"
    with FileLock(f"{done}.lock"):
        if not done.is_file():  # the CLI writes atomically: a file there is a whole one
            assert main(["calibrate", str(PAPER), "--out", str(done), *FAST]) == 0
    out = tmp_path_factory.mktemp("session") / "paper.json"
    shutil.copyfile(done, out)
    return out


@pytest.fixture(scope="session")
def paper_result(paper_result_file):
    """The session's paper calibration, read back from its file."""
    from handeye_jax import load_result

    return load_result(paper_result_file)


@pytest.fixture(scope="session")
def paper_l1_result():
    """The paper's data fitted under its own loss (``l1``, the mean error length; the tests'
    budget), diagnosed: for what the paper's loss determines (its optima, its refits)."""
    from dataclasses import replace

    from handeye_jax import calibrate, diagnose, load_dataset
    from tests.common import FAST_SETTINGS, PAPER

    with jax.enable_x64(True):
        return diagnose(calibrate(load_dataset(PAPER), replace(FAST_SETTINGS, loss="l1")))
