"""What a result can and cannot tell, read-only: uncertainty and identifiability, the optima
left in the DE populations, leave-one-out refits, the hand-angle convention check and where
the calibration holds (scope). Diagnostics never change a result's parameters."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
# fmt: off
_EXPORTS = {
    "_bootstrap": ("bootstrap", "resample", "resamples_of", "with_bootstrap"),
    "_diagnose": ("diagnose",),
    "_scope": ("capture_scope", "scope_lines"),
}
# fmt: on
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
