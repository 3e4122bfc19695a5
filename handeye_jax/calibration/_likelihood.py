"""A stage's maximum-likelihood fit under the noise model (the ``ml`` loss).

The search (DE, LM, restarts, refits) finds the optimum's basin on the paper's F. From its
optimum, LM minimises the noise model's −2 log-likelihood (:class:`~handeye_jax.NoiseObjective`;
with a prior, the posterior's), and the pictures' and touches' noise scales are estimated from
the residuals (:func:`~handeye_jax.estimate_noise`); the two alternate until the scales
settle. A recalibration keeps the noise of the result it starts from: its prior was computed
under that noise, and a few new touches cannot estimate it.
"""

from __future__ import annotations

import math
from dataclasses import replace

import jax.numpy as jnp
import numpy as np

from ..data import Observations
from ..models import AbstractModel
from ..optim import Box, LevenbergMarquardt, minimise_starts
from ..problem import (
    AbstractObjective,
    NoiseFit,
    NoiseModel,
    NoiseObjective,
    ParameterSpace,
    PriorObjective,
    estimate_noise,
    noise_objective,
    put,
    row_counts,
)
from ._stage import StageFit, with_prior

#: At most this many rounds of (LM, scale estimate).
NOISE_ROUNDS = 5
#: The rounds stop once no scale changes by more than this fraction.
SCALE_TOLERANCE = 0.01
#: How the polish summary names the refinement.
REFINED = "; then maximum likelihood under the noise model"
#: The refinement's LM: host-side iterations over one compiled residual-and-Jacobian program
#: (optimistix's LM would compile a loop of its own for each objective: seconds, cold).
ML_POLISH = LevenbergMarquardt(rtol=1e-12, atol=0.0, max_steps=200)


def polish(objective: AbstractObjective, box: Box, x: np.ndarray) -> np.ndarray:
    """LM on ``objective`` from ``x`` in ``box`` (:data:`ML_POLISH`): the end point, or ``x``
    where it does not lower the objective."""
    out = minimise_starts(objective, ML_POLISH, box, np.asarray(x, dtype=float)[None])
    return np.asarray(out.x[0], dtype=float) if np.isfinite(out.value[0]) else np.asarray(x)


def ml_objective(
    data: AbstractObjective,
    space: ParameterSpace,
    n: int,
    noise: NoiseModel,
    model1: AbstractModel,
    obs: Observations,
) -> AbstractObjective:
    """The stage's ML objective: ``data`` (the paper's) under ``noise``, the views'
    covariances at stage-1 model ``model1``, with ``space``'s prior."""
    return with_prior(noise_objective(data, noise, model1, obs), space, n)


def noise_part(objective: AbstractObjective) -> NoiseObjective:
    """The :class:`~handeye_jax.NoiseObjective` inside an ML objective (a prior around it)."""
    while not isinstance(objective, NoiseObjective):
        objective = objective.base
    return objective


def prior_information(space: ParameterSpace) -> np.ndarray | None:
    """A prior's precision in the space's free coordinates (zeros elsewhere), or ``None``."""
    if space.prior is None:
        return None
    P = np.zeros((space.d, space.d))
    idx = space.prior_indices()
    P[np.ix_(idx, idx)] = space.prior.precision
    return P


def refine_ml(
    fit: StageFit,
    noise: NoiseModel,
    obs: Observations,
    model1: AbstractModel | None = None,
    *,
    estimate: bool = True,
) -> tuple[StageFit, NoiseFit]:
    """``fit`` (a stage's optimum on the paper's F) refined to the maximum of the likelihood
    under ``noise``, and the noise it ends with.

    Args:
        fit: the stage's fit.
        noise: the noise model to start from.
        obs: the observations (stage 2's are stage 1's).
        model1: stage 2: the stage-1 model its points come from; stage 1: ``None`` (its own).
        estimate: estimate the scales from the residuals (else keep ``noise``'s).
    """
    space = fit.space
    n = obs.n_landmarks
    counts = row_counts(obs)
    prior = prior_information(space)
    x = np.asarray(fit.x, dtype=float)
    if space.d == 0:  # nothing free: the noise alone
        objective = ml_objective(fit.data, space, n, noise, _stage1(fit, model1, x), obs)
        found = estimate_noise(noise_part(objective), jnp.asarray(x), noise, prior, counts)
        return replace(fit, objective=objective), found if estimate else replace(found, noise=noise)
    for _ in range(NOISE_ROUNDS):
        objective = ml_objective(fit.data, space, n, noise, _stage1(fit, model1, x), obs)
        x = polish(objective, space.box, x)
        found = estimate_noise(noise_part(objective), jnp.asarray(x), noise, prior, counts)
        if not estimate:
            found = replace(found, noise=noise)
            break
        change = max(abs(math.log(found.noise.view_scale / noise.view_scale)),
                     abs(math.log(found.noise.depth_scale_or_view / noise.depth_scale_or_view)),
                     abs(math.log(found.noise.touch_scale / noise.touch_scale)))  # fmt: skip
        noise = found.noise
        if change < SCALE_TOLERANCE:
            break
    objective = ml_objective(fit.data, space, n, noise, _stage1(fit, model1, x), obs)
    x = polish(objective, space.box, x)  # the last scales' optimum
    summary = replace(fit.polish, found_by=(fit.polish.found_by or "DE") + REFINED)
    return replace(fit, objective=objective, x=x, polish=summary), found


def _stage1(fit: StageFit, model1: AbstractModel | None, x: np.ndarray) -> AbstractModel:
    """The stage-1 model the views' covariances are taken at."""
    if model1 is not None:
        return model1
    return put(fit.space.template, fit.space.free, jnp.asarray(x))


def is_ml(objective: AbstractObjective) -> bool:
    """Whether a stage's objective is the noise model's (a prior around it or not)."""
    while isinstance(objective, PriorObjective):
        objective = objective.base
    return isinstance(objective, NoiseObjective)
