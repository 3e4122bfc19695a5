"""Field-by-field reading of parsed documents (TOML, JSON) with one-line errors."""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Any

from .errors import InputError


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
