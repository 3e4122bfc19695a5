"""One stage's fit, its parts: what a stage is given (:class:`StageTask`), what it gives
(:class:`StageFit`), the prior it adds and the polish it runs. The search itself (DE over the
searched parameters, then LM over every free parameter from DE's best member, from restarts
and, in stage 1, from the multi-start refits; the lowest value any of them reaches is the
stage's optimum) is :func:`~._search.fit_stages`, for one problem or a batch."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from ..models import AbstractParametric
from ..optim import (
    DESolution,
    LevenbergMarquardt,
)
from ..problem import (
    AbstractObjective,
    GaussianObjective,
    LossObjective,
    NoiseObjective,
    ParameterSpace,
    PriorObjective,
    put,
)
from ._payloads import (
    Convergence,
    DESummary,
    PolishSummary,
)

#: The polish of one stage's optimum: optimistix's LM to tight tolerances.
POLISH = LevenbergMarquardt(rtol=1e-12, atol=1e-12, max_steps=1000)


#: Most LM iterations of each restart (the batch stops earlier once none improves).
RESTART_STEPS = 400


#: A restart or refit replaces the fit only when its value is lower by more than this, mm
#: (an equal one, e.g. the sign twin's, keeps the fit).
BETTER_BY_MM = 1e-9


def with_prior(
    objective: AbstractObjective, space: ParameterSpace, n: int, *, gaussian: bool = True
) -> AbstractObjective:
    """``objective`` (on ``space.free``) with ``space``'s prior as a ``prior`` block.

    A prior that states the noise σ of the fit it came from (a previous result's posterior)
    also turns the paper's error lengths into Gaussian errors of that σ
    (:class:`~handeye_jax.GaussianObjective`): one noise model for the prior and the data. A
    robust loss the user chose stays as it is. Under the noise model
    (:class:`~handeye_jax.NoiseObjective`) the prior's block is its −2 log-density over n.

    Args:
        objective: the data objective.
        space: the free parameters and their prior.
        n: the number of landmarks behind each data block.
        gaussian: whether the data may become Gaussian (False: a robust loss wraps the result).
    """
    prior = space.prior
    if prior is None:
        return objective
    inner = objective.base if isinstance(objective, LossObjective) else objective
    if isinstance(inner, NoiseObjective):
        # The data's blocks are χ²/n (−2 log-likelihood over n): the prior's, likewise.
        return PriorObjective(objective, space.prior_indices(), jnp.asarray(prior.mean),
                              jnp.asarray(prior.whitener()), jnp.asarray(2.0 / n))  # fmt: skip
    if gaussian and prior.data_sigma_mm is not None and not isinstance(objective, LossObjective):
        scale = prior.data_scale_mm / (2.0 * prior.data_sigma_mm**2)
        objective = GaussianObjective(objective, jnp.asarray(scale))
    return PriorObjective(
        objective, space.prior_indices(), jnp.asarray(prior.mean), jnp.asarray(prior.whitener()),
        jnp.asarray(prior.data_scale_mm / n),
    )  # fmt: skip


@dataclass(frozen=True)
class Population:
    """A DE run's final population, for the restarts and the diagnostics.

    Attributes:
        members: the members in the searched parameters, ``(N, k)``.
        values: what each member's objective value is, ``(N,)``.
        searched: the names of the searched parameters, in column order.
    """

    members: np.ndarray
    values: np.ndarray
    searched: tuple[str, ...]


@dataclass(frozen=True)
class StageFit:
    """One stage's optimum in the fit's own terms (before it becomes a :class:`StageResult`).

    Attributes:
        space: the stage's parameters.
        objective: what the stage minimised (loss and prior included), on ``space.free``.
        data: the paper's objective on ``space.free`` (the stage's F).
        x: the optimum's free parameters.
        de, polish, convergence: the DE and LM summaries and the DE's history.
        timings: seconds of DE and of the polish.
        population: the final DE population (``None`` without DE), for the diagnostics.
    """

    space: ParameterSpace
    objective: AbstractObjective
    data: AbstractObjective
    x: np.ndarray
    de: DESummary
    polish: PolishSummary
    convergence: Convergence
    timings: dict[str, float]
    population: Population | None = None

    def model(self) -> AbstractParametric:
        """The template with the optimum put in."""
        return put(self.space.template, self.space.free, jnp.asarray(self.x))


@dataclass(frozen=True)
class StageTask:
    """One stage to fit, and how its search runs.

    Attributes:
        build: the stage's data objective for a template and the names of its free
            parameters (the loss applied, no prior).
        space: the stage's parameters, box and prior.
        search: the free parameters DE searches (``None``: all); the others start at the
            template's values. An empty search skips DE.
        n_landmarks: landmarks behind each data block (the prior's weight is ``s/n``).
        label: the progress bar's label.
        restart_landmarks: the landmarks the restarts and refits search on (default: all).
        refit_starts: start points of the multi-start refits in ``space``'s box (stage 1:
            :func:`refit_starts`, and the closed-form estimate's), or ``None``.
        refit_labels: what each refit start is (default: uniform starts).
    """

    build: Callable[[AbstractParametric, tuple[str, ...]], AbstractObjective]
    space: ParameterSpace
    n_landmarks: int
    search: tuple[str, ...] | None = None
    label: str = "DE"
    restart_landmarks: np.ndarray | None = None
    refit_starts: np.ndarray | None = None
    refit_labels: tuple[str, ...] | None = None


@dataclass(frozen=True)
class DESearch:
    """What DE searched: the subspace (all free parameters, or the task's ``search``), its
    objective (prior conditioned on the others) and the start of the others."""

    space: ParameterSpace
    objective: AbstractObjective
    base: np.ndarray
    de: DESolution


def de_summary(search, found: DESearch | None, value: float) -> tuple[DESummary, Convergence]:
    """The result's ``de`` summary and ``convergence`` history of a stage's DE."""
    if found is None:
        return DESummary(searched=tuple(search)), Convergence()
    de = found.de
    # F: the whole objective's value at DE's best (equal to DE's own with a full search).
    info = DESummary(searched=tuple(search), F_mm=value, generations=de.steps,
                     evaluations=de.evaluations, converged=de.converged)  # fmt: skip
    convergence = Convergence(
        best_F_mm=tuple(float(v) for v in de.best_history),
        median_F_mm=tuple(float(v) for v in de.median_history),
        median_generation=tuple(int(g) for g in de.median_generations),
    )
    return info, convergence


#: A refit that lands within this fraction of every parameter's range of the fit has refined
#: the fit's own optimum rather than found another.
MODE_PARAM_FRACTION = 0.01
