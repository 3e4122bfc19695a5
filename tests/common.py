"""What the tests share besides fixtures (those are in ``conftest.py``): paths and budgets."""

from pathlib import Path

from handeye_jax import Settings

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "data" / "paper2023.toml"
#: The tests' DE budget, as command-line options and as settings: every fit with it shares
#: the compiled programs of the session's paper calibration.
FAST = ["--population", "200", "--generations", "400", "--no-progress"]
FAST_SETTINGS = Settings(population=200, generations=400)
#: Restarts for a noise-free twin's fit, whose checks do not read the restarts: DE and LM find
#: the truth, and LM from a far start crawls towards it for all of its 400 iterations, so 32
#: restarts cost most of such a fit (benchmarks/RESULTS.md, twenty-third session).
EXACT_RESTARTS = 4
