"""The two-stage calibration: one generic stage fit (:mod:`._search`), run for the model and
then for the correction on the model's chain points (:mod:`._batch`, for one dataset or many).

:func:`fit` runs any :class:`Plan`; :func:`calibrate` fits every parameter; :func:`recalibrate`
starts from a previous result (the paper's open problem: another pen, a moved tablet, a
remounted camera); :func:`fit_correction` is stage 2 alone (the oracle's, on a twin). The
search for the best optimum is the fit's, all of it; the diagnostics
(:func:`handeye_jax.diagnose`) only read a result.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import jax
import numpy as np
from jax.sharding import Mesh

from .._jax import in_float64, single_device_mesh
from ..data import Dataset
from ..models import AbstractCorrection, AbstractModel, AffinePair, get_model
from ..problem import NoiseModel, ParameterSpace
from ._batch import WAVE, check_shared, fit_batch, timed, with_plan_time
from ._plans import Plan, full_plan, recalibration_plan
from ._programs import rotation_centres, stage_keys
from ._result import CalibrationResult, StageResult
from ._rig_change import check_rig
from ._search import fit_stages
from ._settings import Settings
from ._stage import StageFit
from ._stage_result import finished_stage
from ._tasks import Run, likelihood, padded_obs, stage2_task


@in_float64
def fit(
    dataset: Dataset, plan: Plan, settings: Settings = Settings(), *, progress: bool = False
) -> CalibrationResult:
    """Fit both stages of ``plan`` to ``dataset``; the engine of :func:`calibrate` and
    :func:`recalibrate`. The result holds the best optimum the search found; the diagnostics
    (:func:`handeye_jax.diagnose`) only read it. It is a batch of one
    (:func:`~handeye_jax.calibrate_batch`), on one device.

    Args:
        dataset: a validated dataset.
        plan: what each stage fits.
        settings: DE, LM and restart settings.
        progress: show each stage's DE progress bar on stderr.
    """
    out = fit_batch([dataset], [plan], [settings], mesh=single_device_mesh(),
                    stage_progress=progress)[0]  # fmt: skip
    if isinstance(out, Exception):
        raise out
    return out


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
    task, points = stage2_task(run, model, space2, search2)
    pad = padded_obs(run)  # on the rows calibrate's stage 2 runs on, so the two compare
    padded = None if pad is None else [stage2_task(run, model, space2, search2, pad[2])[0].build]
    fit2 = fit_stages([task], run.settings, [keys2], padded=padded,
                      mask=None if pad is None else pad[1][None],
                      mesh=single_device_mesh(), progress=run.progress)[0]  # fmt: skip
    fit2, noise2 = likelihood(fit2, run, noise, model, estimate=estimate)
    stage2 = replace(finished_stage(fit2, "stage 2", run.source), noise=noise2)
    return fit2, stage2, np.asarray(rotation_centres(fit2.model(), points, run.obs.centre_index))


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
    plan, plan_s = timed(full_plan, dataset, settings)
    return with_plan_time(fit(dataset, plan, settings, progress=progress), plan_s)


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
    (plan, settings, changes), plan_s = timed(_recalibration, dataset, previous, refit,
                                              settings, fix, source, accept_rig_change)  # fmt: skip
    result = with_plan_time(fit(dataset, plan, settings, progress=progress), plan_s)
    return _with_changes(result, changes)


def _recalibration(
    dataset: Dataset,
    previous: CalibrationResult,
    refit: Sequence[str],
    settings: Settings | None,
    fix: bool,
    source: str | Path | None,
    accept_rig_change: bool,
) -> tuple[Plan, Settings, tuple]:
    """A recalibration's plan, settings and rig changes (see :func:`recalibrate`)."""
    if settings is None:
        settings = previous.settings
    if settings.model != previous.model_name:
        raise ValueError(f"the previous result is of model {previous.model_name!r}, settings "
                         f"say {settings.model!r}")  # fmt: skip
    source = str(source) if source is not None else f"previous result ({previous.dataset_name})"
    changes = check_rig(dataset, previous, source, accept_rig_change)
    with jax.enable_x64(True):
        plan = recalibration_plan(dataset, previous, refit, fix=fix, source=source,
                                  preset=settings.search)  # fmt: skip
    return plan, settings, changes


def _with_changes(result: CalibrationResult, changes) -> CalibrationResult:
    if not changes:
        return result
    return replace(result, recalibration=replace(result.recalibration, rig_changes=changes))


@in_float64
def recalibrate_batch(
    datasets: Sequence[Dataset],
    previous: CalibrationResult | Sequence[CalibrationResult],
    refit: Sequence[str],
    settings: Settings | Sequence[Settings] | None = None,
    *,
    fix: bool = False,
    progress: bool = False,
    wave: int = WAVE,
    mesh: Mesh | None = None,
) -> list[CalibrationResult]:
    """:func:`recalibrate` of every dataset, in one batch (as :func:`calibrate_batch` is to
    :func:`calibrate`): result ``i`` is ``recalibrate(datasets[i], previous[i], refit,
    settings[i], fix=fix)``'s, bit for bit. A dataset whose rig differs from its previous
    result's (intrinsics, tablet pixel size, hand-angle convention) raises the
    :class:`InputError` :func:`recalibrate` raises without ``accept_rig_change``.

    Args:
        datasets: the new measurements, one per problem.
        previous: the earlier calibration, one for all or one per dataset.
        refit: the groups or parameters that changed (the same for every problem).
        settings: one for all, or one per dataset, differing in ``seed`` only (default: each
            previous result's).
        fix: hold the other parameters at the previous values instead of giving them a prior.
        progress: a progress bar over the problems on stderr.
        wave: the most problems per device fitted at once.
        mesh: the devices (default: all of this process's).
    """
    n = len(datasets)
    olds = [previous] * n if isinstance(previous, CalibrationResult) else list(previous)
    each = ([settings] * n if settings is None or isinstance(settings, Settings)
            else list(settings))  # fmt: skip
    if len(olds) != n or len(each) != n:
        raise ValueError(f"{len(olds)} previous results and {len(each)} settings for {n} "
                         "datasets")  # fmt: skip
    timed_made = [timed(_recalibration, d, o, refit, s, fix, None, False)
                  for d, o, s in zip(datasets, olds, each, strict=True)]  # fmt: skip
    made = [m for m, _ in timed_made]
    check_shared([m[1] for m in made])
    outcomes = fit_batch(datasets, [m[0] for m in made], [m[1] for m in made],
                         progress=progress, wave=wave, mesh=mesh)  # fmt: skip
    for out in outcomes:
        if isinstance(out, Exception):
            raise out
    return [_with_changes(with_plan_time(r, plan_s), m[2])
            for r, (m, plan_s) in zip(outcomes, timed_made, strict=True)]  # fmt: skip


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
    _, keys2 = stage_keys(np.int64(settings.seed))
    space2 = ParameterSpace.all_free(AffinePair.nominal(), dataset.search)
    run = Run(dataset.observations(), settings, source=dataset.source)
    fit2, _, centres = fit_correction_stage(run, model, space2, space2.free, keys2)
    return fit2.model(), centres


# -- what the diagnostics read of a result -------------------------------------------------
