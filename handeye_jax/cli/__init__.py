"""``handeye-jax``: the command line, a thin layer over the Python API: one module per command
group, the shared argument types once. Importing it imports no JAX, so ``--help`` is quick."""

from ._main import MODELS, PROG, build_parser, main, run

__all__ = ["MODELS", "PROG", "build_parser", "main", "run"]
