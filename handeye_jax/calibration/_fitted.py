"""What the diagnostics read of a result: each stage as its fit saw it."""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from .._core import InputError, Stages
from .._jax import in_float64
from ..problem import (
    AbstractObjective,
    L1Loss,
    ParameterSpace,
    Stage1Objective,
    Stage2Objective,
    get_loss,
    put,
)
from ._likelihood import ml_objective
from ._plans import spaces_of
from ._programs import points_of
from ._result import CalibrationResult
from ._stage import Population, with_prior


@dataclass(frozen=True)
class FittedStage:
    """One stage of a result as its fit saw it, for the diagnostics to read.

    Attributes:
        space: the stage's parameters, box and prior.
        objective: the stage's objective on ``space.free`` as fitted, its prior included and
            the loss not (stage 2 at stage 1's chain points).
        x: the optimum's free parameters.
        population: the final DE population, if the result was just computed.
    """

    space: ParameterSpace
    objective: AbstractObjective
    x: np.ndarray
    population: Population | None = None


@in_float64
def fitted_stages(result: CalibrationResult, search: dict | None = None) -> Stages[FittedStage]:
    """Both stages of ``result`` as fitted: from its fits when it was just computed, else
    rebuilt from its file's numbers (``search``: the dataset's ``[search]`` overrides, which a
    file does not record)."""
    if result.data is None:
        raise InputError(None, "data", "the result does not carry its data: it cannot be "
                         "diagnosed; calibrate again")  # fmt: skip
    obs = result.data.observations()
    n = obs.n_landmarks
    if result.fits is not None:
        spaces = Stages(result.fits.stage1.space, result.fits.stage2.space)
        xs = Stages(result.fits.stage1.x, result.fits.stage2.x)
        populations = Stages(result.fits.stage1.population, result.fits.stage2.population)
    else:
        spaces = spaces_of(result, search or {})
        xs = Stages(*(np.array([s.params[nm] for nm in sp.free])
                      for sp, s in ((spaces.stage1, result.stage1),
                                    (spaces.stage2, result.stage2))))  # fmt: skip
        populations = Stages(None, None)
    # Gaussian data under a prior that states its noise, unless a robust loss was chosen: as
    # the fit's objectives (with_prior).
    gaussian = isinstance(get_loss(result.settings.loss, result.settings.loss_scale_mm), L1Loss)
    sp1, sp2 = spaces.stage1, spaces.stage2
    model1 = put(sp1.template, sp1.free, jnp.asarray(xs.stage1))
    data1 = Stage1Objective(sp1.template, obs, sp1.free)
    points = points_of(model1, obs)
    data2 = Stage2Objective(sp2.template, points, obs.centre_index, sp2.free)
    if result.stage1.noise is not None and result.stage2.noise is not None:
        # The maximum-likelihood fit's objectives, with the noise each stage ended with.
        s1 = ml_objective(data1, sp1, n, result.stage1.noise.noise, model1, obs)
        s2 = ml_objective(data2, sp2, n, result.stage2.noise.noise, model1, obs)
    else:
        s1 = with_prior(data1, sp1, n, gaussian=gaussian)
        s2 = with_prior(data2, sp2, n, gaussian=gaussian)
    return Stages(FittedStage(sp1, s1, xs.stage1, populations.stage1),
                  FittedStage(sp2, s2, xs.stage2, populations.stage2))  # fmt: skip
