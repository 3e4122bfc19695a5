"""The two-stage calibration: one generic stage fit (:mod:`._stage`), run for the model and
then for the correction on the model's chain points.

:func:`fit` runs any :class:`Plan`; :func:`calibrate` fits every parameter; :func:`recalibrate`
starts from a previous result (the paper's open problem: another pen, a moved tablet, a
remounted camera); :func:`fit_correction` is stage 2 alone (the oracle's, on a twin). The
search for the best optimum is the fit's, all of it; the diagnostics
(:func:`handeye_jax.diagnose`) only read a result.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._core import MAX_RESTARTS, Stages
from .._jax import in_float64
from ..data import Dataset, Observations, check_distinct, check_population
from ..models import AbstractCorrection, AbstractModel, AffinePair, get_model
from ..problem import (
    L1Loss,
    LossObjective,
    NoiseFit,
    NoiseModel,
    ParameterSpace,
    Stage1Objective,
    Stage2Objective,
    get_loss,
    get_noise_model,
    height_summary,
    spread_landmarks,
)
from ._likelihood import refine_ml
from ._payloads import (
    NO_EVIDENCE,
    Recalibration,
)
from ._plans import Plan, full_plan, recalibration_plan
from ._programs import _centres, _points, _stage_keys
from ._result import CalibrationResult, StageResult
from ._rig_change import check_rig
from ._settings import Settings
from ._stage import StageFit, StageTask, fit_stage
from ._stage_result import _finished, _sign_twin
from ._starts import refit_starts
from ._warnings import all_warnings, check_determined

#: Above this many landmarks the restarts search on this many, spread over the touch order,
#: and only the best end point is polished on all: the restarts' cost stays bounded.
RESTART_LANDMARKS = 64


# -- both stages ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Run:
    """What both stages of one calibration share: the observations fitted, the settings,
    whether progress bars show, and the data's source (named in an error)."""

    obs: Observations
    settings: Settings
    progress: bool = False
    source: str | Path | None = None


def _loss_wrapper(settings: Settings, n: int):
    loss = get_loss(settings.loss, settings.loss_scale_mm)

    def with_loss(objective):  # the paper's F stays the plain objective (and its compiled code)
        if isinstance(loss, L1Loss):
            return objective
        return LossObjective(objective, loss, jnp.ones(n))

    return with_loss


@in_float64
def fit(
    dataset: Dataset, plan: Plan, settings: Settings = Settings(), *, progress: bool = False
) -> CalibrationResult:
    """Fit both stages of ``plan`` to ``dataset``; the engine of :func:`calibrate` and
    :func:`recalibrate`. The result holds the best optimum the search found; the diagnostics
    (:func:`handeye_jax.diagnose`) only read it."""
    t_start = time.perf_counter()
    obs = _checked(dataset, plan, settings)
    run = Run(obs, settings, progress, dataset.source)
    n = obs.n_landmarks
    keys1, keys2 = _stage_keys(np.int64(settings.seed))
    with_loss = _loss_wrapper(settings, n)
    subset1 = spread_landmarks(n, RESTART_LANDMARKS) if n > RESTART_LANDMARKS else None

    def build1(template, free):
        return with_loss(Stage1Objective(template, obs, free))

    task1 = StageTask(build1, plan.space1, n, plan.search1, "stage 1 DE", subset1,
                      refit_starts(settings.seed, plan.space1.box, obs.rig))  # fmt: skip
    fit1 = fit_stage(task1, settings, keys1, progress=progress)
    fit1, noise1 = _likelihood(fit1, run, plan.noise1, None, estimate=plan.previous is None)
    stage1 = replace(_finished(fit1, "stage 1", dataset.source), noise=noise1)
    fit2, stage2, centres = fit_correction_stage(run, fit1.model(), plan.space2, plan.search2,
                                                 keys2, noise=plan.noise2,
                                                 estimate=plan.previous is None)  # fmt: skip
    spaces, stages = Stages(plan.space1, plan.space2), Stages(stage1, stage2)
    timings = {
        "stage1_de": fit1.timings["de"], "stage1_polish": fit1.timings["polish"],
        "stage2_de": fit2.timings["de"], "stage2_polish": fit2.timings["polish"],
        "total": time.perf_counter() - t_start,
    }  # fmt: skip
    recal = None
    if plan.previous is not None:
        recal = Recalibration(plan.previous, tuple(plan.refit), "fixed" if plan.fixed else "prior")
    return CalibrationResult(
        model=fit1.model(), correction=fit2.model(), rig=obs.rig, centres_mm=np.asarray(centres),
        centre_index=obs.centre_index, stage1=stage1, stage2=stage2, settings=settings,
        data=dataset, dataset_name=dataset.name, timings_s=timings, sign_twin=_sign_twin(fit1),
        warnings=all_warnings(n, spaces, stages, dataset.search, dataset.source),
        recalibration=recal, fits=Stages(fit1, fit2), heights=height_summary(fit1.model(), obs),
        deploy=NO_EVIDENCE,
    )  # fmt: skip


def _checked(dataset: Dataset, plan: Plan, settings: Settings) -> Observations:
    """The dataset's observations, once the plan, the settings and the data can make a fit
    (an undetermined one is refused before any work; its warnings come with the result)."""
    model_cls = type(plan.space1.template)
    if settings.model != model_cls.name:
        raise ValueError(f"settings.model is {settings.model!r}, the plan's {model_cls.name!r}")
    if not 0 <= settings.seed < 2**63:  # refused now, not by the diagnostics after the fit
        raise ValueError(f"seed must be 0 to 2^63 - 1: numpy's generators take no other seed "
                         f"(got {settings.seed})")  # fmt: skip
    check_population(dataset, settings.population)
    if not 0 <= settings.restarts <= MAX_RESTARTS:
        raise ValueError(f"restarts must be 0 to {MAX_RESTARTS:,} (got {settings.restarts})")
    obs = dataset.observations()
    check_determined(obs.n_landmarks, plan.space1, "stage 1", dataset.source)
    check_determined(obs.n_landmarks, plan.space2, "stage 2", dataset.source)
    check_distinct(dataset.tablet_px, dataset.source)
    return obs


def _likelihood(fit: StageFit, run: Run, noise: NoiseModel | None, model1, *,
                estimate: bool) -> tuple[StageFit, NoiseFit | None]:  # fmt: skip
    """``fit`` refined to maximum likelihood under the noise model when the settings' loss is
    ``ml`` (starting from ``noise``, default the settings' preset), and the noise it found."""
    if run.settings.loss != "ml":
        return fit, None
    start = noise if noise is not None else get_noise_model(run.settings.noise)
    return refine_ml(fit, start, run.obs, model1, estimate=estimate)


def fit_correction_stage(
    run: Run,
    model: AbstractModel,
    space2: ParameterSpace,
    search2: Sequence[str],
    keys2: tuple[jax.Array, jax.Array],
    *,
    noise: NoiseModel | None = None,
    estimate: bool = True,
) -> tuple[StageFit, StageResult, np.ndarray]:
    """Stage 2 on the chain points of a stage-1 ``model``: its fit, its result and its
    centres of rotation (rows: A1, A2), mm. Under the ``ml`` loss it is refined to maximum
    likelihood (from ``noise``; ``estimate``: its scales from the residuals)."""
    obs, settings = run.obs, run.settings
    n = obs.n_landmarks
    points = _points(model, obs)
    with_loss = _loss_wrapper(settings, n)
    subset = None
    if n > RESTART_LANDMARKS:
        subset = spread_landmarks(n, RESTART_LANDMARKS, include=obs.centre_index)

    def build2(template, free):
        return with_loss(Stage2Objective(template, points, obs.centre_index, free))

    task = StageTask(build2, space2, n, tuple(search2), "stage 2 DE", subset)
    fit2 = fit_stage(task, settings, keys2, progress=run.progress)
    fit2, noise2 = _likelihood(fit2, run, noise, model, estimate=estimate)
    stage2 = replace(_finished(fit2, "stage 2", run.source), noise=noise2)
    return fit2, stage2, np.asarray(_centres(fit2.model(), points, obs.centre_index))


def calibrate(
    dataset: Dataset, settings: Settings = Settings(), *, progress: bool = False
) -> CalibrationResult:
    """Fit the stage-1 model and the stage-2 correction to a dataset, every parameter free.

    Each stage's optimum is the lowest F found by the DE, the LM polish and the LM restarts;
    the stage's ``polish.found_by`` says which search found it. The diagnostics (uncertainty,
    leave-one-out, convention check) are a separate step, :func:`handeye_jax.diagnose`.

    Args:
        dataset: a validated dataset (see :func:`handeye_jax.load_dataset`).
        settings: model, seed and optimiser settings.
        progress: show progress bars on stderr.
    """
    get_model(settings.model)  # an unknown name fails here, before any work
    return fit(dataset, full_plan(dataset, settings), settings, progress=progress)


# -- recalibration -------------------------------------------------------------------------


def recalibrate(
    dataset: Dataset,
    previous: CalibrationResult,
    refit: Sequence[str],
    settings: Settings | None = None,
    *,
    fix: bool = False,
    source: str | Path | None = None,
    progress: bool = False,
    accept_rig_change: bool = False,
) -> CalibrationResult:
    """Recalibrate after a part of the rig changed, from a previous result.

    The parameters of the ``refit`` groups (``camera``, ``tablet``, ``pen``, or single
    parameter names) are searched by DE within their ranges; every other parameter takes the
    previous result's posterior as its prior (a MAP fit), or with ``fix`` is held at the
    previous value; then LM polishes all free parameters. Stage 2 starts from the previous
    correction likewise. A prior lets a dataset of a few landmarks determine the fit.

    Args:
        dataset: the new measurements (any number of landmarks the fit can determine).
        previous: the earlier calibration of this rig.
        refit: the groups or parameters that changed.
        settings: DE and LM settings (default: the previous result's).
        fix: hold the other parameters at the previous values instead of giving them a prior.
        source: where ``previous`` came from, for the report (default: its dataset's name).
        progress: show progress bars on stderr.
        accept_rig_change: take data whose intrinsics, tablet pixel size or hand-angle
            convention differ from ``previous``'s (a re-calibrated camera); without it they
            are an :class:`InputError` naming the field. The result records the change.
    """
    if settings is None:
        settings = previous.settings
    if settings.model != previous.model_name:
        raise ValueError(f"the previous result is of model {previous.model_name!r}, settings "
                         f"say {settings.model!r}")  # fmt: skip
    source = str(source) if source is not None else f"previous result ({previous.dataset_name})"
    changes = check_rig(dataset, previous, source, accept_rig_change)
    with jax.enable_x64(True):
        plan = recalibration_plan(dataset, previous, refit, fix=fix, source=source)
    result = fit(dataset, plan, settings, progress=progress)
    if changes:
        recal = replace(result.recalibration, rig_changes=changes)
        result = replace(result, recalibration=recal)
    return result


@in_float64
def fit_correction(
    dataset: Dataset, model: AbstractModel, settings: Settings = Settings()
) -> tuple[AbstractCorrection, np.ndarray]:
    """Stage 2 alone: fit the affine correction to a dataset with a given stage-1 model.

    With the true model (on synthetic data) this is the oracle's stage 2. The DE key is the
    one :func:`calibrate` uses for its stage 2, so the two are comparable seed for seed.

    Returns:
        The fitted correction and its centres of rotation (rows: A1, A2), mm.
    """
    _, keys2 = _stage_keys(np.int64(settings.seed))
    space2 = ParameterSpace.all_free(AffinePair.nominal(), dataset.search)
    run = Run(dataset.observations(), settings, source=dataset.source)
    fit2, _, centres = fit_correction_stage(run, model, space2, space2.free, keys2)
    return fit2.model(), centres


# -- what the diagnostics read of a result -------------------------------------------------
