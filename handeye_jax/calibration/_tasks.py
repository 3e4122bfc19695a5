"""What one calibration's fit is made of, built the same way for one dataset and for a batch:
the run (observations, settings), the rows its objectives are padded to, each stage's task,
and the result assembled from both stages' fits."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._core import MAX_RESTARTS, Stages
from ..data import Dataset, Observations, check_distinct, check_population
from ..models import AbstractModel
from ..problem import (
    ChainPoints,
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
    pad_rows,
    spread_landmarks,
)
from ._advice import AdviceContext, analyses_of
from ._likelihood import refine_ml
from ._payloads import NO_EVIDENCE, Recalibration
from ._plans import Plan
from ._programs import points_of
from ._result import CalibrationResult, StageResult
from ._settings import Settings
from ._stage import StageFit, StageTask
from ._stage_result import sign_twin_of
from ._starts import refit_starts
from ._warnings import all_warnings, check_determined

#: Above this many landmarks the restarts search on this many, spread over the touch order,
#: and only the best end point is polished on all: the restarts' cost stays bounded.
RESTART_LANDMARKS = 64


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



def likelihood(fit: StageFit, run: Run, noise: NoiseModel | None, model1, *,
               estimate: bool) -> tuple[StageFit, NoiseFit | None]:  # fmt: skip
    """``fit`` refined to maximum likelihood under the noise model when the settings' loss is
    ``ml`` (starting from ``noise``, default the settings' preset), and the noise it found
    (``model1``: stage 2's stage-1 model, ``None`` in stage 1; ``estimate``: the noise's
    scales from the residuals)."""
    if run.settings.loss != "ml":
        return fit, None
    start = noise if noise is not None else get_noise_model(run.settings.noise)
    return refine_ml(fit, start, run.obs, model1, estimate=estimate)


def checked(dataset: Dataset, plan: Plan, settings: Settings) -> Observations:
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


#: Up to this many rows a problem's objectives are its own; above, they run on its rows padded
#: (:func:`padded_rows`).
EXACT_ROWS = 16


def padded_rows(obs: Observations) -> int | None:
    """The rows a problem's objectives run on, padded with rows of weight 0 so that problems
    of nearby sizes share a batch's programs (``None``: its own, unpadded): up to
    :data:`EXACT_ROWS` rows, and with the hand's heights, its own; then the next multiple of
    8 up to :data:`RESTART_LANDMARKS`, of 64 above. It depends on the problem alone, so a
    problem runs on the same rows alone and in any batch."""
    n = obs.n_landmarks
    if n <= EXACT_ROWS or obs.hand_z_mm is not None:
        return None
    step = 8 if n <= RESTART_LANDMARKS else 64
    return -(-n // step) * step


def padded_obs(run: Run) -> tuple[Observations, np.ndarray, np.ndarray] | None:
    """The run's observations padded to :func:`padded_rows`, their rows' weights, and which
    row each padded row copies (``None``: not padded)."""
    rows = padded_rows(run.obs)
    if rows is None:
        return None
    obs, mask = pad_rows(run.obs, rows)
    n = run.obs.n_landmarks
    return obs, mask, np.concatenate([np.arange(n), np.zeros(rows - n, int)])


def stage1_task(run: Run, plan: Plan, obs: Observations | None = None) -> StageTask:
    """Stage 1's task for a run (on ``obs``, default the run's: a batch pads them)."""
    n = run.obs.n_landmarks
    obs = run.obs if obs is None else obs
    with_loss = _loss_wrapper(run.settings, obs.n_landmarks)
    subset1 = spread_landmarks(n, RESTART_LANDMARKS) if n > RESTART_LANDMARKS else None

    def build1(template, free):
        return with_loss(Stage1Objective(template, obs, free))

    starts1 = refit_starts(run.settings.seed, plan.space1.box, run.obs.rig)
    labels1 = None
    if plan.starts1 is not None and len(plan.starts1):  # the closed-form estimate's, polished
        labels1 = tuple(f"LM from a uniform start (refit {i + 1} of {len(starts1)})"
                        for i in range(len(starts1))) + tuple(plan.labels1)  # fmt: skip
        starts1 = np.concatenate([starts1, plan.space1.clip(plan.starts1)])
    return StageTask(build1, plan.space1, n, plan.search1, "stage 1 DE", subset1, starts1,
                     labels1)  # fmt: skip


@dataclass(frozen=True)
class Job:
    """One calibration to fit: its dataset, plan and run."""

    dataset: Dataset
    plan: Plan
    run: Run


def assemble(
    job: Job,
    fits: Stages[StageFit],
    stages: Stages[StageResult],
    *,
    centres: np.ndarray,
    total_s: float,
) -> CalibrationResult:
    """The result of both stages' fits (``total_s``: the seconds the whole fit took)."""
    dataset, plan, run = job.dataset, job.plan, job.run
    fit1, fit2 = fits.stage1, fits.stage2
    timings = {
        "stage1_de": fit1.timings["de"], "stage1_polish": fit1.timings["polish"],
        "stage2_de": fit2.timings["de"], "stage2_polish": fit2.timings["polish"],
        "total": total_s,
    }  # fmt: skip
    recal = None
    if plan.previous is not None:
        recal = Recalibration(plan.previous, tuple(plan.refit), "fixed" if plan.fixed else "prior")
    obs, n = run.obs, run.obs.n_landmarks
    spaces = Stages(plan.space1, plan.space2)
    return CalibrationResult(
        model=fit1.model(), correction=fit2.model(), rig=obs.rig, centres_mm=np.asarray(centres),
        centre_index=obs.centre_index, stage1=stages.stage1, stage2=stages.stage2,
        settings=run.settings, data=dataset, dataset_name=dataset.name, timings_s=timings,
        sign_twin=sign_twin_of(fit1),
        warnings=all_warnings(n, spaces, stages, dataset.source,
                              advice=AdviceContext(plan.search, obs, analyses_of(fits))),
        recalibration=recal, fits=fits, heights=height_summary(fit1.model(), obs),
        search=plan.search, deploy=NO_EVIDENCE,
    )  # fmt: skip


def stage2_task(
    run: Run, model: AbstractModel, space2: ParameterSpace, search2: Sequence[str],
    rows: np.ndarray | None = None,
) -> tuple[StageTask, ChainPoints]:  # fmt: skip
    """Stage 2's task on the chain points of a stage-1 ``model``, and those points (with
    ``rows``, the task's objective is on the points of those rows: a batch pads them)."""
    obs, settings = run.obs, run.settings
    n = obs.n_landmarks
    points = points_of(model, obs)
    on = points if rows is None else jax.tree.map(lambda a: np.asarray(a)[rows], points)
    with_loss = _loss_wrapper(settings, n if rows is None else len(rows))
    subset = None
    if n > RESTART_LANDMARKS:
        subset = spread_landmarks(n, RESTART_LANDMARKS, include=obs.centre_index)

    def build2(template, free):
        return with_loss(Stage2Objective(template, on, obs.centre_index, free))

    return StageTask(build2, space2, n, tuple(search2), "stage 2 DE", subset), points
