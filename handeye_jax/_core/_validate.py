"""Field-by-field reading of parsed documents (TOML, JSON) with one-line errors."""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Any

from ._errors import InputError


def describe(x: Any) -> str:
    """A short description of a TOML value for error messages."""
    if x is None:  # JSON's null; TOML has none
        return "null"
    if isinstance(x, bool):
        return f"boolean {str(x).lower()}"
    if isinstance(x, int | float):
        return f"{'integer' if isinstance(x, int) else 'float'} {x}"
    if isinstance(x, str):
        text = repr(x)
        return f"string {text if len(text) <= 40 else text[:37] + '...'}"
    if isinstance(x, list):
        return f"an array of {len(x)}"
    if isinstance(x, dict):
        return "a table"
    return f"a {type(x).__name__}"


#: Largest magnitudes a field may have: far beyond any rig, but small enough that nothing
#: derived from them (products, squares, a fit's residuals) overflows float64.
MAX_PX = 1e6
MAX_MM = 1e5
MAX_DEG = 3600.0

# Sizes: what the toolkit can compute on one machine (docs/file-formats.md's "Limits" list them).
#: Landmarks in a dataset, a result or a twin's truth.
MAX_LANDMARKS = 10_000
#: DE population and generations (calibrate's options; a result's settings): ten times the
#: paper's 10,000 each.
MAX_POPULATION = 100_000
MAX_GENERATIONS = 100_000
#: LM restarts a stage (calibrate's settings): each holds a Jacobian of at most 4·65 × 12
#: residuals while the batch runs, so this many take about 1 GB.
MAX_RESTARTS = 10_000
#: DE population times landmarks: DE's working memory is about 48 bytes per member and
#: landmark (benchmarks/RESULTS.md, "Figures the code's comments point to"), so this is
#: about 5 GB. The paper's N = 10,000 fits 10,000
#: landmarks.
MAX_MEMBER_LANDMARKS = 100_000_000
#: Points in a points CSV (predict) or held-out targets (simulate --heldout, heldout.csv).
MAX_POINTS = 100_000
MAX_HELDOUT = 10_000
#: Pixels in a picture or depth image (detect) and in a twin's picture: 4096 x 4096.
MAX_IMAGE_PIXELS = 4096 * 4096

# Plausibility: values a rig cannot have.
#: Largest angle between an image point's ray and the optical axis, deg: a pinhole picture
#: wider than 160 deg does not exist.
MAX_RAY_DEG = 80.0
#: Size of one tablet px, mm (25.4 / ppi * scale): from a 2,540 ppi panel at scale 1 to a
#: 25 ppi wall display at scale 3; a screen's pixel is within this.
MM_PER_TABLET_PX = (0.01, 3.0)


def parse_int(text: str) -> int:
    """An integer in ASCII digits, as a command-line value or CSV cell is written.

    Python's ``int`` also reads ``"１２"`` (full-width) and ``"1_000"``, which no user means;
    raises ``ValueError`` for them.
    """
    if not text.isascii() or "_" in text:
        raise ValueError(f"not a whole number: {text!r}")
    return int(text)


def parse_float(text: str) -> float:
    """A number in ASCII (``"3.5"``, ``"-1e3"``, ``"nan"``): :func:`parse_int`'s rule for floats."""
    if not text.isascii() or "_" in text:
        raise ValueError(f"not a number: {text!r}")
    return float(text)


def parse_numbers(text: str, limit: float, unit: str, n: int | None = None) -> list[float]:
    """Comma-separated finite numbers (``"320,-70,290"``), each at most ``limit`` in size, and
    ``n`` of them if given; ``ValueError`` with a one-line reason otherwise."""
    parts = [part.strip() for part in text.split(",")]
    if n is not None and len(parts) != n:
        raise ValueError(f"needs {n} numbers, comma-separated (got {len(parts)}: {text!r})")
    out = []
    for part in parts:
        try:
            v = parse_float(part)
        except ValueError:
            raise ValueError(f"not a number: {part!r}") from None
        if not abs(v) <= limit:  # NaN fails too
            raise ValueError(f"must be finite, at most {limit:g} {unit} in size (got {part})")
        out.append(v)
    return out


class Reader:
    """Pulls typed fields out of a parsed TOML document, naming the field on failure."""

    def __init__(self, path: Path | None):
        self.path = path

    def fail(self, where: str, message: str):
        raise InputError(self.path, where, message)

    def table(self, value: Any, where: str, keys: tuple[str, ...], optional: tuple[str, ...] = ()):
        """Check that ``value`` is a table holding exactly ``keys`` (``optional`` may be absent)."""
        if not isinstance(value, dict):
            self.fail(where, f"must be a table (got {describe(value)})")
        missing = [k for k in keys if k not in value and k not in optional]
        for k in value:
            if k not in keys:
                hint = difflib.get_close_matches(k, missing or keys, n=1)
                expected = f"did you mean {hint[0]!r}?" if hint else f"expected {', '.join(keys)}"
                self.fail(join_key(where, k), f"unknown key; {expected}")
        if missing:
            self.fail(join_key(where, missing[0]), "missing")
        return value

    def number(
        self,
        x: Any,
        where: str,
        positive: bool = False,
        limit: float | None = None,
        minimum: float | None = None,
        unit: str = "",
    ) -> float:
        """A finite float; ``positive``: > 0; ``limit``: at most this in magnitude;
        ``minimum``: at least this (``unit`` names its unit in the message)."""
        if isinstance(x, bool) or not isinstance(x, int | float):
            self.fail(where, f"must be a number (got {describe(x)})")
        try:
            value = float(x)
        except OverflowError:  # an integer beyond float64's range
            self.fail(where, f"must be finite (got an integer of {len(str(abs(x)))} digits)")
        if not math.isfinite(value):
            self.fail(where, f"must be finite (got {x})")
        if positive and value <= 0:
            self.fail(where, f"must be > 0 (got {x})")
        if minimum is not None and value < minimum:
            self.fail(where, f"must be at least {minimum:g}{' ' + unit if unit else ''} (got {x})")
        if limit is not None and abs(value) > limit:
            self.fail(where, f"must be at most {limit:g} in magnitude (got {x})")
        return value

    def vector(self, x: Any, where: str, n: int, limit: float | None = None) -> list[float]:
        if not isinstance(x, list) or len(x) != n:
            self.fail(where, f"must be an array of {n} numbers (got {describe(x)})")
        return [self.number(v, f"{where}[{i}]", limit=limit) for i, v in enumerate(x)]


def join_key(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key
