"""The suite's shared fixtures: one calibration of the paper's data per test process,
reused by every file that needs a result (``paper_result_file``, ``paper_result``)."""

import os
from pathlib import Path

import jax
import pytest

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


@pytest.fixture(autouse=True)
def _float64():
    """Tests run in float64 the same way users do: scoped, not by flipping global config."""
    with jax.enable_x64(True):
        yield


@pytest.fixture(scope="session")
def paper_result_file(tmp_path_factory) -> Path:
    """The paper's data calibrated as the command line does it (the tests' budget, with
    diagnostics), once per test process: the result file. Read it; do not change it."""
    from handeye_jax.cli import main
    from tests.common import FAST, PAPER

    out = tmp_path_factory.mktemp("session") / "paper.json"
    assert main(["calibrate", str(PAPER), "--out", str(out), *FAST]) == 0
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
