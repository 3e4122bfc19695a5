"""``python -m handeye_jax.cli``."""

from ._main import run

run()
