"""What each stage fits (:class:`Plan`): every parameter free, or a recalibration's refitted
groups with a previous result's posterior as the prior (or its values held); and the spaces
of a result read back from its file."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .._core import Stages
from .._jax import in_float64
from ..data import Dataset
from ..models import AffinePair, get_model
from ..problem import (
    FIXED,
    NoiseModel,
    ParameterSpace,
    Prior,
    resolve_names,
)
from ._payloads import (
    PriorReport,
)
from ._ranges import SearchRange, SearchReport, plan_search, resolve_preset, searched_box
from ._result import CalibrationResult
from ._settings import Settings


@dataclass(frozen=True)
class Plan:
    """What each stage fits: its parameters, what DE searches, and where the rest came from.

    Attributes:
        space1, space2: the stages' parameter spaces.
        search1, search2: the parameters DE searches in each stage.
        previous: the result the plan starts from (its file or ``None``).
        refit: the groups or parameters refitted, when starting from a previous result.
        fixed: the other parameters were held at the previous values (not given a prior).
        starts1, labels1: further LM starts of stage 1 (in ``space1``'s box) and what each is
            (the closed-form estimate's polished candidates), or ``None``.
        search: where the stages searched (:class:`SearchReport`), or ``None``.
        noise1, noise2: the noise model each stage's maximum-likelihood fit starts from
            (``None``: the settings' preset); a recalibration's is its previous result's.
    """

    space1: ParameterSpace
    space2: ParameterSpace
    search1: tuple[str, ...]
    search2: tuple[str, ...]
    previous: str | None = None
    refit: tuple[str, ...] = ()
    fixed: bool = False
    extra: dict[str, Any] = field(default_factory=dict)
    starts1: np.ndarray | None = None
    labels1: tuple[str, ...] = ()
    search: SearchReport | None = None
    noise1: NoiseModel | None = None
    noise2: NoiseModel | None = None


@in_float64
def full_plan(dataset: Dataset, settings: Settings) -> Plan:
    """Every parameter of both stages free in its search range (:func:`plan_search`: around
    the closed-form estimate of the rig by default, or the paper's ranges)."""
    model_cls = get_model(settings.model)
    where = plan_search(dataset, model_cls, settings.search)
    space1 = ParameterSpace(model_cls.nominal(), model_cls.param_names, where.box1.lower,
                            where.box1.upper)  # fmt: skip
    space2 = ParameterSpace(AffinePair.nominal(), AffinePair.param_names, where.box2.lower,
                            where.box2.upper)  # fmt: skip
    return Plan(space1, space2, space1.free, space2.free, starts1=where.starts1,
                labels1=where.labels1, search=where.report)  # fmt: skip


#: The prior's data scale ``s`` is the previous fit's F over this (the maximum-likelihood
#: scale of 2-D errors with density ∝ exp(−|e|/s), whose mean length is 2s, over two terms).
F_PER_SCALE = 4.0


#: A prior parameter's box is widened to hold its prior mean ± this many σ.
PRIOR_BOX_SIGMAS = 6.0


def _previous_prior(previous: CalibrationResult, stage: str, names: Sequence[str], source: str):
    """The previous result's posterior over its free parameters of ``stage``, marginalised to
    ``names`` (those it had free; the rest stay as they were)."""
    posterior = previous.posterior(stage, source=source)
    mine = [n for n in names if n in posterior.names]
    return posterior.marginal(mine) if mine else None


def _widened(cls, search, names, prior: Prior | None, template,
             bounds: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The box of ``names``: ``bounds`` (all of ``cls``'s parameters; default: its preset
    ranges with ``search``) widened to hold the template's values and the prior mean ± 6σ."""
    lo, hi = cls.search_bounds(search) if bounds is None else bounds
    idx = [cls.param_names.index(n) for n in names]
    lo, hi = lo[idx], hi[idx]
    values = np.array([float(getattr(template, n)) for n in names])
    lo, hi = np.minimum(lo, values), np.maximum(hi, values)
    if prior is not None:
        sig = prior.sigma
        for j, name in enumerate(prior.names):
            if name in names and math.isfinite(sig[j]):
                k = list(names).index(name)
                lo[k] = min(lo[k], prior.mean[j] - PRIOR_BOX_SIGMAS * sig[j])
                hi[k] = max(hi[k], prior.mean[j] + PRIOR_BOX_SIGMAS * sig[j])
    return lo, hi


def _around_previous(cls, template, search: dict, preset: str) -> tuple[np.ndarray, np.ndarray]:
    """A recalibration's ranges before they are widened to hold the prior: with the
    ``estimate`` preset each parameter's previous value ± half its paper range (a part that
    changed moves by about as much as those allow, from wherever the rig is); with ``paper``
    the paper's ranges; the dataset's ``[search]`` ranges replace either."""
    lo, hi = cls.search_bounds()
    if preset == "estimate":
        values = np.array([float(getattr(template, n)) for n in cls.param_names])
        half = (hi - lo) / 2.0
        lo, hi = values - half, values + half
    for i, name in enumerate(cls.param_names):
        if name in search:
            lo[i], hi[i] = search[name]
    return lo, hi


def _recalibration_report(preset: str, spaces: tuple, search: dict) -> SearchReport:
    """Where a recalibration searched: each free parameter's box as fitted (the others keep
    the preset's ranges, for the record)."""
    stages = []
    for space in spaces:
        cls = type(space.template)
        lo, hi = cls.search_bounds()
        ranges = {}
        for i, name in enumerate(cls.param_names):
            if name in space.free:
                j = space.free.index(name)
                source = "[search]" if name in search else (
                    "previous" if preset == "estimate" else "paper")  # fmt: skip
                ranges[name] = SearchRange(float(space.lower[j]), float(space.upper[j]), source)
            else:
                ranges[name] = SearchRange(float(lo[i]), float(hi[i]), "default")
        stages.append(ranges)
    return SearchReport(preset, stages[0], stages[1])


def recalibration_plan(
    dataset: Dataset,
    previous: CalibrationResult,
    refit: Sequence[str],
    *,
    fix: bool = False,
    source: str = "previous result",
    preset: str | None = None,
) -> Plan:
    """Stage 1 with the ``refit`` groups (or parameters) searched afresh and the others taken
    from ``previous``: as its posterior for a prior, or (``fix``) held at its values. Stage 2
    starts from the previous correction, with its posterior as the prior (or held, ``fix``).

    The ranges: with the ``estimate`` preset (``None``: the dataset's, else ``estimate``) each
    parameter's previous value ± half its paper range; with ``paper`` the paper's; either
    widened to hold the previous values and the prior's mean ± 6σ, and replaced by the
    dataset's ``[search]`` ranges.
    """
    preset = resolve_preset(dataset, preset)
    model_cls = type(previous.model)
    refit_names = resolve_names(model_cls, refit)
    if not refit_names:
        raise ValueError("nothing to refit: name a group (camera, tablet, pen) or a parameter")
    template1 = previous.model
    template2 = previous.correction
    prev_free1 = [n for n, st in previous.stage1.status.items() if st != FIXED]
    prev_free2 = [n for n, st in previous.stage2.status.items() if st != FIXED]
    was_fixed = {n: previous.stage1.fixed_source.get(n, source)
                 for n in model_cls.param_names if n not in prev_free1}  # fmt: skip
    others = [n for n in model_cls.param_names if n not in refit_names and n in prev_free1]
    scale1 = previous.stage1.F / F_PER_SCALE
    scale2 = previous.stage2.F / F_PER_SCALE
    box1 = _around_previous(model_cls, template1, dataset.search, preset)
    if fix:
        lo, hi = _widened(model_cls, dataset.search, refit_names, None, template1, box1)
        space1 = ParameterSpace(template1, refit_names, lo, hi, None,
                                {**was_fixed, **dict.fromkeys(others, source)})  # fmt: skip
        lo2, hi2 = _widened(AffinePair, dataset.search, (), None, template2)
        space2 = ParameterSpace(template2, (), lo2, hi2, None,
                                dict.fromkeys(AffinePair.param_names, source))  # fmt: skip
    else:
        free1 = tuple(n for n in model_cls.param_names if n in refit_names or n in others)
        prior1 = _previous_prior(previous, "stage1", others, source)
        if prior1 is not None:
            prior1 = replace(prior1, data_scale_mm=scale1)
        lo, hi = _widened(model_cls, dataset.search, free1, prior1, template1, box1)
        space1 = ParameterSpace(template1, free1, lo, hi, prior1, was_fixed)
        prior2 = _previous_prior(previous, "stage2", prev_free2, source)
        if prior2 is not None:
            prior2 = replace(prior2, data_scale_mm=scale2)
        free2 = tuple(prev_free2)
        lo2, hi2 = _widened(AffinePair, dataset.search, free2, prior2, template2)
        space2 = ParameterSpace(template2, free2, lo2, hi2, prior2)
    report = _recalibration_report(preset, (space1, space2), dataset.search)
    noises = [None if s.noise is None else s.noise.noise
              for s in (previous.stage1, previous.stage2)]  # fmt: skip
    return Plan(space1, space2, refit_names, (), source, tuple(refit), fix, search=report,
                noise1=noises[0], noise2=noises[1])


def _prior_of(report: PriorReport | None) -> Prior | None:
    if report is None:
        return None
    return Prior(report.names, report.mean, report.precision, report.source, report.data_scale_mm,
                 report.data_sigma_mm, report.untested, report.alternatives)  # fmt: skip


def spaces_of(result: CalibrationResult, search: dict) -> Stages[ParameterSpace]:
    """The stages' parameter spaces of a result read from a file (its boxes: the ranges it
    searched, or for an older result the preset's with ``search``, widened to hold the fit
    and its priors)."""
    spaces = []
    for template, stage, key in ((result.model, result.stage1, "stage1"),
                                 (result.correction, result.stage2, "stage2")):  # fmt: skip
        cls = type(template)
        free = tuple(n for n in cls.param_names if n in stage.free())
        prior = _prior_of(stage.prior)
        bounds = searched_box(cls, result.search, key, search)
        lo, hi = _widened(cls, search, free, prior, template, bounds)
        spaces.append(ParameterSpace(template, free, lo, hi, prior, stage.fixed_source))
    return Stages(*spaces)
