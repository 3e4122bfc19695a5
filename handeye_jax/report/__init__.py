"""For people: the printed summary of a calibration and its figures (PNG and SVG)."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_figures": ("render", "write_report"),
    "_summary": ("format_summary",),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
