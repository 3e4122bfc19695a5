"""What a result can and cannot tell, read-only: uncertainty and identifiability, the optima
left in the DE populations, leave-one-out refits, the hand-angle convention check and where
the calibration holds (scope). Diagnostics never change a result's parameters."""

from __future__ import annotations

from .._core import lazy_exports

# What the layers above may use, by module; each loads on first use (PEP 562).
_EXPORTS = {
    "_diagnostics": ("bound_hits", "diagnostics_of", "MAX_MODES", "mode_leaders"),
    "_refits": ("REFIT_LANDMARKS",),
    "_scope": ("capture_scope", "scope_lines"),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
