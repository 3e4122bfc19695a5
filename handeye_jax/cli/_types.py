"""The command line's parser, the argument types its commands share and the words they share,
each written once.

A type turns the text of one option into its value or raises ``ArgumentTypeError``, which the
parser prints as one line naming the option. Imports no JAX.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path

from .._core import (
    MAX_BOOTSTRAP,
    MAX_GENERATIONS,
    MAX_LANDMARKS,
    MAX_POPULATION,
    MAX_RESTARTS,
    check_output,
    parse_float,
    parse_int,
    parse_numbers,
)
from .._core import (
    TWIN_SEED_RANGE as SEED_RANGE,
)

PROG = "handeye-jax"
#: The models ``--model`` offers: ``models.model_registry()`` (JAX) names the same (tested).
MODELS = ("dh", "htm")


class HelpFormatter(argparse.HelpFormatter):
    """Every option's help ends with its default, unless the help already names it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if not action.option_strings or "default" in text.lower():
            return text
        if action.default is False and action.nargs == 0:  # a flag: off unless given
            return f"{text} (default: off)"
        if action.default is None or action.default is argparse.SUPPRESS:
            return text  # such options say in their help what happens without them
        return f"{text} (default: %(default)s)"


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line, with no usage block."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def output_path(
    path: str | Path | None, option: str = "--out", inputs: Sequence[str | Path | None] = ()
) -> Path | None:
    """The output file of ``option``, checked before the work: its folder exists and can be
    written, and it is not a folder nor one of the command's ``inputs``."""
    return None if path is None else check_output(path, option, inputs)


def whole_number(text: str, lo: int | None = None, hi: int | None = None) -> int:
    """An integer in ASCII digits, from ``lo`` to ``hi`` when given."""
    try:
        v = parse_int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if lo is not None and v < lo or hi is not None and v > hi:
        most = f"{lo} to {hi:,}" if hi is not None else f"at least {lo}"
        raise argparse.ArgumentTypeError(f"must be {most} (got {v})")
    return v


def positive_int(text: str) -> int:
    return whole_number(text, 1)


def population(text: str) -> int:
    v = positive_int(text)
    if v < 4:
        raise argparse.ArgumentTypeError(f"DE/rand/1 needs at least 4 members (got {v})")
    if v > MAX_POPULATION:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_POPULATION:,} (got {v})")
    return v


def generations(text: str) -> int:
    v = positive_int(text)
    if v > MAX_GENERATIONS:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_GENERATIONS:,} (got {v})")
    return v


def restarts(text: str) -> int:
    return whole_number(text, 0, MAX_RESTARTS)


def resamples(text: str) -> int:
    """``--bootstrap``'s B: how many resamples to refit, 1 to :data:`MAX_BOOTSTRAP`."""
    return whole_number(text, 1, MAX_BOOTSTRAP)


def seed(text: str) -> int:
    """A seed of NumPy's generators (the diagnostics' and the twin's): 0 to 2^63 - 1."""
    v = whole_number(text)
    if not SEED_RANGE[0] <= v <= SEED_RANGE[1]:
        why = f"must be 0 to 2^63 - 1: numpy's generators take no other seed (got {v})"
        raise argparse.ArgumentTypeError(why)
    return v


def port(text: str) -> int:
    try:
        v = parse_int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"must be 0 to 65535 (got {v})")
    return v


def _number(text: str) -> float:
    try:
        return parse_float(text)  # ASCII only
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def positive_number(text: str) -> float:
    v = _number(text)
    if not 0 < v < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0 (got {text})")
    return v


def positive_mm(text: str) -> float:
    v = _number(text)
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite length > 0 mm (got {text})")
    return v


def number_at_most(limit: float) -> Callable[[str], float]:
    """A number > 0 and at most ``limit``."""

    def parse(text: str) -> float:
        v = _number(text)
        if not 0 < v <= limit:
            raise argparse.ArgumentTypeError(f"must be > 0 and at most {limit:g} (got {text})")
        return v

    return parse


def numbers(limit: float, unit: str, n: int | None = None) -> Callable[[str], list[float]]:
    """Comma-separated numbers in ``unit``, each at most ``limit`` in size (``n`` of them when
    given)."""

    def parse(text: str) -> list[float]:
        try:
            return parse_numbers(text, limit, unit, n)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    return parse


def landmark_indices(text: str) -> tuple[int, ...]:
    """Comma-separated landmark numbers m (``"0,4,8"``): whole numbers, each once. Whether
    the dataset has them is checked once it is read."""
    parts = [part.strip() for part in text.split(",")]
    ms = tuple(whole_number(part, 0, MAX_LANDMARKS - 1) for part in parts)
    twice = sorted({m for m in ms if ms.count(m) > 1})
    if twice:
        raise argparse.ArgumentTypeError(f"{landmarks_named(twice)} given twice")
    return ms


def landmarks_named(ms) -> str:
    """``landmark 3`` or ``landmarks 3, 5``."""
    ms = list(ms)
    return ("landmark " if len(ms) == 1 else "landmarks ") + ", ".join(map(str, ms))
