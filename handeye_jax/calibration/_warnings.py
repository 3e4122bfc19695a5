"""What a user should know about a fit, one line each: a fit no rig gives, a stage with no
residuals to spare (or too few: refused), parameters on a bound of their search range,
prior parameters the data pull away."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._core import InputError, Stages
from ..problem import (
    ParameterSpace,
)
from ._advice import AdviceContext, bound_hits, bound_warning
from ._payloads import (
    BoundHit,
    FitWarning,
)
from ._result import StageResult

#: A prior's parameter is flagged when the data pull it this many σ from the prior's mean.
PULL_FLAG = 3.0


#: Each landmark gives four residual scalars (x and y of both terms of the objective).
RESIDUALS_PER_LANDMARK = 4


def check_determined(
    n_landmarks: int, space: ParameterSpace, stage: str, path: str | Path | None
) -> list[FitWarning]:
    """Refuse a stage with fewer residuals than free parameters; warn when none are left over.

    Each landmark gives four residual scalars; a prior gives one per direction it informs.
    Returns the warnings (a fit with no degrees of freedom left).
    """
    prior_rank = 0
    if space.prior is not None:
        w = np.linalg.eigvalsh(space.prior.precision)
        prior_rank = int(np.sum(w > 1e-12 * max(float(w.max()), 1e-300)))
    residuals = RESIDUALS_PER_LANDMARK * n_landmarks + prior_rank
    d = space.d
    with_prior = f" and {prior_rank} from the prior" if prior_rank else ""
    if residuals < d:
        need = math.ceil((d - prior_rank) / RESIDUALS_PER_LANDMARK)
        raise InputError(
            path, "landmarks",
            f"{stage} has {d} free parameters but only {residuals} residuals ({n_landmarks} "
            f"landmarks x {RESIDUALS_PER_LANDMARK}{with_prior}): it needs at least {need} "
            "landmarks, or fewer free parameters (recalibrate with --prior and --refit)",
        )  # fmt: skip
    if residuals == d:
        return [FitWarning(
            f"{stage} has as many residuals ({residuals}: {n_landmarks} landmarks x "
            f"{RESIDUALS_PER_LANDMARK}{with_prior}) as free parameters: it can match the data "
            "exactly, so its F says nothing about its accuracy; touch more landmarks",
            "residuals",
        )]  # fmt: skip
    return []


#: A fit whose F is above this, mm, is no rig's: the paper's is 0.36 mm.
F_DOES_NOT_FIT_MM = 100.0


def fit_warnings(stage1: StageResult, stage2: StageResult,
                 outside: Sequence[BoundHit] = ()) -> list[FitWarning]:  # fmt: skip
    """A plain warning when F is so large that the data cannot be a rig's: the ranges
    searched, when the closed-form estimate puts parameters ``outside`` them; else the data."""
    F = max(stage1.F, stage2.F)
    if F <= F_DOES_NOT_FIT_MM:
        return []
    if outside:
        names = ", ".join(h.param for h in outside)
        return [FitWarning(
            f"the data do not fit in the ranges searched: F = {F:.4g} mm, more than "
            f"{F_DOES_NOT_FIT_MM:g} mm (a working rig fits to about 1 mm); do not use this "
            f"result. The closed-form estimate from the data puts {names} outside the ranges "
            "(below): the rig is not where they assume", "fit",
        )]  # fmt: skip
    return [FitWarning(
        f"the data do not fit: F = {F:.4g} mm, more than {F_DOES_NOT_FIT_MM:g} mm (a working "
        "rig fits to about 1 mm); do not use this result. Check the dataset's units (mm, deg, "
        "px), [tablet] ppi and scale, [camera], and the hand-angle convention", "fit",
    )]  # fmt: skip


#: A model whose best F1st is above this many times the closed-form frames' F (and 1 mm more)
#: cannot hold the rig the data describe.
MODEL_CANNOT_HOLD = 3.0


def model_warnings(model_cls, stage1: StageResult, report) -> list[FitWarning]:
    """A warning when the model cannot hold the rig: its best F1st far above the F of the
    closed-form frames in the six-DoF chain (the search report's ``frames_F_mm``)."""
    frames = None if report is None else report.frames_F_mm
    if frames is None or stage1.F <= MODEL_CANNOT_HOLD * frames + 1.0:
        return []
    return [FitWarning(
        f"the {model_cls.name.upper()} model cannot hold this rig: its best F1st is "
        f"{stage1.F:.4g} mm, while the closed-form estimate of the rig's frames fits to "
        f"{frames:.4g} mm in the six-DoF chain; a model's chain may fix some of the frames "
        f"(DH, eqs. 12-16: the camera on the hand's x axis, the tablet's origin on the base's "
        f"x axis), which another robot's base frame need not satisfy: use --model htm", "fit",
    )]  # fmt: skip


def prior_warnings(stage: StageResult, label: str) -> list[FitWarning]:
    """One warning per prior parameter the data pull more than :data:`PULL_FLAG` σ away,
    largest pull first (the likeliest to have changed; correlated ones follow it)."""
    prior = stage.prior
    if prior is None:
        return []
    out = []
    for p in sorted(prior.pulls, key=lambda p: -abs(p.pull)):
        if abs(p.pull) > PULL_FLAG and p.follows is None and p.param not in prior.untested:
            sigma = "" if p.sigma is None else f" ± {p.sigma:.3g}"
            following = [f.param for f in sorted(prior.pulls, key=lambda f: -abs(f.pull))
                         if f.follows == p.param]  # fmt: skip
            tail = ""
            if following:
                tail = (f"; {', '.join(following)} follow{'s' if len(following) == 1 else ''} "
                        f"it (their pulls vanish once {p.param} moves)")  # fmt: skip
            out.append(FitWarning(
                f"{label}: the data pull {p.param} {abs(p.pull):.1f} sigma from its prior "
                f"({prior.source}: {p.mean:.4g}{sigma}; fitted {p.value:.4g}){tail}: the prior "
                f"may be wrong for this rig; refit {p.param} (--refit) instead", "prior", p.param,
            ))  # fmt: skip
    return out


def _following_stage1(stage2: StageResult) -> list[FitWarning]:
    """Stage 2's prior checks, when stage 1's prior is pulled, as one line: the correction's
    prior was fitted on the previous stage 1's chain points, so a stage-1 parameter that moved
    pulls it too (with a right prior, neither is flagged: benchmarks/RESULTS.md)."""
    pulled = prior_warnings(stage2, "stage 2")
    if not pulled:
        return []
    pulls = {p.param: abs(p.pull) for p in stage2.prior.pulls}
    names = ", ".join(f"{w.param} {pulls[w.param]:.1f}" for w in pulled)
    return [FitWarning(
        f"stage 2: the data pull its prior too ({names} sigma): the correction's prior was "
        f"fitted on the previous stage 1, so it follows stage 1's prior check above; recheck "
        f"it once that is resolved", "prior",
    )]  # fmt: skip


def all_warnings(
    n: int,
    spaces: Stages[ParameterSpace],
    stages: Stages[StageResult],
    path: str | Path | None,
    extra: Sequence[FitWarning] = (),
    advice: AdviceContext | None = None,
) -> list[FitWarning]:
    """Every warning of a fit of ``n`` landmarks: a fit that is no rig's, stages with no
    residuals to spare, parameters on a bound of the range searched (with what would help,
    from ``advice``), priors the data pull from, and ``extra`` ones (the diagnostics'), one
    line each."""
    stage1, stage2 = stages.stage1, stages.stage2
    hits = [*bound_hits(stage1, spaces.stage1, "stage1", advice),
            *bound_hits(stage2, spaces.stage2, "stage2", advice)]  # fmt: skip
    outside = [h for h in hits if h.reason == "estimate outside"]
    if outside:  # the ranges do not hold this rig: the other bounds hit follow from that
        hits = outside
    report = None if advice is None else advice.report
    held = model_warnings(type(spaces.stage1.template), stage1, report)
    if held:  # the model cannot hold this rig: its bounds say nothing more
        hits = []
    warnings = held or fit_warnings(stage1, stage2, outside)
    warnings += check_determined(n, spaces.stage1, "stage 1", path)
    warnings += check_determined(n, spaces.stage2, "stage 2", path)
    warnings += [FitWarning(bound_warning(h), "bound", h.param) for h in hits]
    first = prior_warnings(stage1, "stage 1")
    warnings += first + (_following_stage1(stage2) if first else prior_warnings(stage2, "stage 2"))
    return warnings + list(extra)
