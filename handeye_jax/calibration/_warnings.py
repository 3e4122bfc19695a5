"""What a user should know about a fit, one line each: a fit no rig gives, a stage with no
residuals to spare (or too few: refused), parameters on a bound of their search range,
prior parameters the data pull away."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._core import InputError, Stages
from ..models import AbstractParametric, AffinePair
from ..problem import (
    ParameterSpace,
)
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


#: A parameter closer than this fraction of its range to a bound is on the bound.
BOUND_FRACTION = 1e-3


def bound_hits(
    params: dict[str, float], cls: type[AbstractParametric], search: dict
) -> tuple[BoundHit, ...]:
    """Parameters on a bound of their search range, each with a wider range to try.

    Args:
        params: the fitted parameters, name → value (in each parameter's unit).
        cls: the model or correction class (names, units, default ranges).
        search: the dataset's ``[search]`` overrides.
    """
    lower, upper = cls.search_bounds(search)
    out = []
    for name, unit, lo, hi in zip(cls.param_names, cls.param_units, lower, upper, strict=True):
        v, width = params[name], hi - lo
        side = (
            "lower"
            if v - lo <= BOUND_FRACTION * width
            else ("upper" if hi - v <= BOUND_FRACTION * width else None)
        )
        if side:
            wider = (lo - width, hi) if side == "lower" else (lo, hi + width)
            out.append(BoundHit(name, float(v), unit, side, (float(lo), float(hi)),
                                (float(wider[0]), float(wider[1]))))  # fmt: skip
    return tuple(out)


def bound_warnings(
    params: dict[str, float],
    cls: type[AbstractParametric],
    search: dict,
    free: Sequence[str] | None = None,
) -> list[FitWarning]:
    """One warning per free parameter sitting on a bound of its search range."""
    out = []
    for hit in bound_hits(params, cls, search):
        if free is not None and hit.param not in free:
            continue
        name, u = hit.param, "" if hit.unit == "1" else f" {hit.unit}"
        (lo, hi), (wlo, whi) = hit.range, hit.widen_to
        out.append(FitWarning(
            f"{name} = {hit.value:.4g}{u} is on the {hit.side} bound of its search range "
            f"[{lo:g}, {hi:g}]; the optimum may lie outside it: widen it in the dataset's "
            f"[search] table, e.g. {name} = [{wlo:g}, {whi:g}]", "bound", name,
        ))  # fmt: skip
    return out


#: A fit whose F is above this, mm, is no rig's: the paper's is 0.36 mm.
F_DOES_NOT_FIT_MM = 100.0


def fit_warnings(stage1: StageResult, stage2: StageResult) -> list[FitWarning]:
    """A plain warning when F is so large that the data cannot be a rig's."""
    F = max(stage1.F, stage2.F)
    if F <= F_DOES_NOT_FIT_MM:
        return []
    return [FitWarning(
        f"the data do not fit: F = {F:.4g} mm, more than {F_DOES_NOT_FIT_MM:g} mm (a working "
        "rig fits to about 1 mm); do not use this result. Check the dataset's units (mm, deg, "
        "px), [tablet] ppi and scale, [camera], and the hand-angle convention", "fit",
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


def all_warnings(
    n: int,
    spaces: Stages[ParameterSpace],
    stages: Stages[StageResult],
    search: dict,
    path: str | Path | None,
    extra: Sequence[FitWarning] = (),
) -> list[FitWarning]:
    """Every warning of a fit of ``n`` landmarks: a fit that is no rig's, stages with no
    residuals to spare, parameters on a bound, priors the data pull from, and ``extra`` ones
    (the diagnostics'), one line each."""
    model_cls = type(spaces.stage1.template)
    stage1, stage2 = stages.stage1, stages.stage2
    warnings = fit_warnings(stage1, stage2)
    warnings += check_determined(n, spaces.stage1, "stage 1", path)
    warnings += check_determined(n, spaces.stage2, "stage 2", path)
    warnings += bound_warnings(stage1.params, model_cls, search, spaces.stage1.free)
    warnings += bound_warnings(stage2.params, AffinePair, search, spaces.stage2.free)
    warnings += prior_warnings(stage1, "stage 1") + prior_warnings(stage2, "stage 2")
    return warnings + list(extra)
