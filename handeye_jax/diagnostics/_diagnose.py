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
from ..problem import get_noise_model
from ._ambiguity import ambiguities
from ._diagnostics import diagnostics_of
from ._mount import MOVES_COMMANDS_MM, mount_report, weak_parameters
from ._scope import capture_scope
from ._verdict import choose_stage, ml_verdict, stage_noise


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
    # Which stage to deploy, the error to expect from it, the fits the data cannot tell apart
    # and where the calibration holds: from what the diagnostics just found.
    deploy = choose_stage(diagnostics.stage1.loo, diagnostics.stage2.loo)
    noise = stage_noise(result.stage1) or get_noise_model(result.settings.noise)
    fits = Stages(result.stage1.noise, result.stage2.noise)
    diagnostics, expected, cov1 = ml_verdict(stages, diagnostics, deploy.stage, noise, obs,
                                             fits)  # fmt: skip
    found = ambiguities(stages.stage1, diagnostics.stage1, noise, obs)
    weak = weak_parameters(diagnostics.stage1, found)
    untested = weak_parameters(diagnostics.stage1, [a for a in found if not a.edge])
    mount = mount_report(result.model, stages.stage1.space.free, cov1, weak,
                         _why_not(diagnostics.stage1, found, weak))  # fmt: skip
    diagnostics = replace(diagnostics, expected=expected, ambiguities=found, mount=mount,
                          weak_params=tuple(sorted(weak)),
                          untested_params=tuple(sorted(untested)))  # fmt: skip
    result = replace(result, diagnostics=diagnostics, deploy=deploy)
    result = replace(result, diagnostics=replace(diagnostics, scope=capture_scope(result)))
    timings = {**result.timings_s, "diagnostics": time.perf_counter() - t0}
    return replace(result, timings_s=timings)


def _why_not(diag, found, weak: set[str]) -> str:
    """Why components leaning on ``weak`` parameters get no σ, in words."""
    reasons = [f"{' and '.join(w.params)} trade off" if w.determined is None
               else f"only {w.determined} is determined" for w in diag.weak_directions]
    # A weak direction's far end (``edge``) is the trade-off already named above.
    reasons += [f"the {a.kind} fits as well" for a in found if not a.edge
                and max(a.here_mm, a.elsewhere_mm[1]) > MOVES_COMMANDS_MM]  # fmt: skip
    return "not determined by these data (" + "; ".join(reasons) + ")" if reasons else ""
