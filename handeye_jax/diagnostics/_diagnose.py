"""The diagnostics step: a result with its ``diagnostics`` added, its parameters untouched."""

from __future__ import annotations

import time
from dataclasses import replace

from .._core import Stages
from .._jax import in_float64
from ..calibration import (
    AdviceContext,
    CalibrationResult,
    FitWarning,
    all_warnings,
    fitted_stages,
)
from ._diagnostics import diagnostics_of
from ._scope import capture_scope


@in_float64
def diagnose(result: CalibrationResult, *, search: dict | None = None) -> CalibrationResult:
    """The result with its ``diagnostics``: uncertainty and identifiability, the optima in
    the final DE populations, bound hits, leave-one-out, outliers, the convention check and
    where the calibration holds; and with the convention check's warning, if any.

    Read-only: the parameters, F and every number of the fit are the result's own. The
    search for the best optimum (DE, LM, restarts and multi-start refits) is the fit's
    (:func:`~handeye_jax.calibrate`).

    Args:
        result: a result just computed, or read from a file (the DE populations are then
            unknown, and the optima in them are not reported).
        search: the dataset's ``[search]`` overrides (a result read from a file does not
            record them; default: none).
    """
    t0 = time.perf_counter()
    search = search or {}
    stages = fitted_stages(result, search)
    obs = result.data.observations()
    results = Stages(result.stage1, result.stage2)
    diagnostics = diagnostics_of(stages, results, result.settings, obs, result.search)
    spaces = stages.map(lambda s: s.space)
    convention = diagnostics.convention.warning
    extra = [FitWarning(convention, "convention")] if convention else []
    advice = AdviceContext(result.search, obs, lambda key: getattr(diagnostics, key))
    warnings = all_warnings(obs.n_landmarks, spaces, results, None, extra, advice)
    timings = {**result.timings_s, "diagnostics": time.perf_counter() - t0}
    result = replace(result, diagnostics=diagnostics, warnings=warnings, timings_s=timings)
    # Where the calibration holds: from the covariance the diagnostics just found.
    return replace(result, diagnostics=replace(diagnostics, scope=capture_scope(result)))
