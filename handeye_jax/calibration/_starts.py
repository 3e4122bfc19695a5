"""Where stage 1's multi-start refits start: the hand-angle conventions, and uniform draws of
the search box (the diagnostics' convention check draws the same points)."""

from __future__ import annotations

import numpy as np

from ..optim import (
    Box,
)

#: The hand-angle conventions ``φ = zero + sign·θh``, ``(zero deg, sign)``, that the
#: multi-start refits and the diagnostics' convention check know.
CONVENTIONS: tuple[tuple[float, int], ...] = tuple(
    (zero, sign) for sign in (1, -1) for zero in (0.0, 90.0, 180.0, 270.0)
)


#: Uniform LM starts per convention (multi-start: on the paper's data 70 % of uniform starts
#: reach the global basin, see ``benchmarks/RESULTS.md``).
REFIT_STARTS = 6


def convention_index(zero_deg: float, sign: float) -> int:
    """The position of ``(zero_deg, sign)`` in :data:`CONVENTIONS` (0 if it is not there)."""
    zero = np.array([c[0] for c in CONVENTIONS])
    signs = np.array([float(c[1]) for c in CONVENTIONS])
    return int(np.argmax((zero == float(zero_deg)) & (signs == float(sign))))


def uniform_starts(seed: int, box: Box, n: int) -> np.ndarray:
    """``n`` uniform points of ``box`` drawn by NumPy's PCG64 from ``seed`` (a negative seed
    is taken modulo 2⁶⁴)."""
    rng = np.random.default_rng(seed % 2**64)
    return rng.uniform(box.lower, box.upper, size=(n, box.d))


def refit_starts(seed: int, box: Box, rig) -> np.ndarray:
    """Stage 1's refit starts: the declared convention's share of the uniform points the
    convention check draws (the same points, so its refits never reach below the fit)."""
    k = convention_index(float(rig.angle_zero_deg), float(rig.angle_sign))
    draws = uniform_starts(seed, box, len(CONVENTIONS) * REFIT_STARTS)
    return draws[k * REFIT_STARTS : (k + 1) * REFIT_STARTS]
