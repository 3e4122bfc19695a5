"""One stage's fit: DE over the searched parameters, then LM over every free parameter from
DE's best member, from restarts and (stage 1) from the multi-start refits; the lowest value
any of them reaches is the stage's optimum."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np

from ..models import AbstractParametric
from ..optim import (
    MAX_MODES,
    Box,
    DESolution,
    LevenbergMarquardt,
    minimise,
    minimise_starts,
    mode_leaders,
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
    RestartSummary,
)
from ._programs import _lhs, _value
from ._settings import Settings

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
            :func:`refit_starts`), or ``None``.
    """

    build: Callable[[AbstractParametric, tuple[str, ...]], AbstractObjective]
    space: ParameterSpace
    n_landmarks: int
    search: tuple[str, ...] | None = None
    label: str = "DE"
    restart_landmarks: np.ndarray | None = None
    refit_starts: np.ndarray | None = None


@dataclass(frozen=True)
class Optimum:
    """The lowest point a stage's search has reached so far, and which search reached it."""

    x: np.ndarray
    value: float
    found_by: str


@dataclass(frozen=True)
class _Search:
    """What DE searched: the subspace (all free parameters, or the task's ``search``), its
    objective (prior conditioned on the others) and the start of the others."""

    space: ParameterSpace
    objective: AbstractObjective
    base: np.ndarray
    de: DESolution


def fit_stage(
    task: StageTask, settings: Settings, keys: tuple[jax.Array, jax.Array], *,
    progress: bool = False,
) -> StageFit:  # fmt: skip
    """Fit one stage: DE over the task's search, then LM over every free parameter from DE's
    best member, from restarts and from the task's refit starts; the lowest value wins.

    Args:
        task: the stage's objective, parameters and search.
        settings: DE, LM and restart settings.
        keys: the DE's key and the restarts' key.
        progress: show DE's progress bar.
    """
    space = task.space
    search = space.free if task.search is None else tuple(task.search)
    objective = with_prior(task.build(space.template, space.free), space, task.n_landmarks)
    if space.d == 0:
        settings = replace(settings, polish=False)
    t0 = time.perf_counter()
    found = _de_search(task, search, settings, keys[0], progress)
    base = space.clip(space.theta())
    x = base if found is None else space.embed(search, found.de.x, base)
    best = Optimum(np.asarray(x), _value(objective, x), "DE" if found else "the previous result")
    de_info, convergence = _de_summary(search, found, best.value)
    t1 = time.perf_counter()
    polish = PolishSummary(ran=settings.polish, accepted=False, F_before_mm=best.value)
    if settings.polish:
        best, polish = _lm_searches(task, objective, found, keys[1], settings, best)
    polish = replace(polish, found_by=best.found_by)
    population = None if found is None else Population(found.de.population,
                                                       found.de.fitness, search)  # fmt: skip
    return StageFit(
        space=space, objective=objective, data=task.build(space.template, space.free),
        x=np.asarray(best.x, dtype=float), de=de_info, polish=polish, convergence=convergence,
        timings={"de": t1 - t0, "polish": time.perf_counter() - t1}, population=population,
    )  # fmt: skip


def _de_search(
    task: StageTask, search: tuple[str, ...], settings: Settings, key, progress: bool
) -> _Search | None:
    """DE over ``search`` (the other free parameters at the template's values), or ``None``
    for an empty search."""
    if not search:
        return None
    space = task.space
    base = space.clip(space.theta())
    sub = space if search == space.free else space.subspace(search, base)
    sub_objective = with_prior(task.build(sub.template, sub.free), sub, task.n_landmarks)
    de = minimise(sub_objective, settings.de(), sub.box, key=key, progress=progress,
                  desc=task.label)  # fmt: skip
    return _Search(sub, sub_objective, base, de)


def _de_summary(search, found: _Search | None, value: float) -> tuple[DESummary, Convergence]:
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


def _lm_searches(task: StageTask, objective, found: _Search | None, key, settings: Settings,
                 best: Optimum) -> tuple[Optimum, PolishSummary]:  # fmt: skip
    """LM from DE's best, then from the restarts and the refits: the lowest point reached,
    and the polish's summary."""
    F_before = best.value
    lm = minimise(objective, POLISH, task.space.box, x0=best.x)
    if np.isfinite(lm.value) and lm.value < best.value:
        best = Optimum(lm.x, lm.value, f"{best.found_by} + LM")
    restarts = None
    if settings.restarts > 0 and found is not None:
        best, restarts = _restarts(task, objective, found, key, settings, best)
    replaced: tuple[float, ...] = ()
    if settings.restarts > 0 and task.refit_starts is not None:  # restarts=0: DE and LM only
        best, replaced = _refits(task, objective, best, settings.restarts)
    return best, PolishSummary(
        ran=True, accepted=bool(best.value < F_before), F_before_mm=F_before, steps=lm.steps,
        solver_converged=lm.converged, restarts=restarts, F_after_mm=best.value,
        replaced_F_mm=replaced,
    )  # fmt: skip


def _restarts(task: StageTask, objective, found: _Search, key, settings: Settings,
              best: Optimum) -> tuple[Optimum, RestartSummary]:  # fmt: skip
    """LM (on the searched parameters) from the final population's other optima and from
    hypercube points, all at once; the best end point, polished on all free parameters,
    replaces ``best`` if lower. Returns it and the ``restarts`` summary."""
    sub, restarts = found.space, settings.restarts
    leaders = mode_leaders(found.de.population, found.de.fitness, sub.lower, sub.upper)[0]
    leaders = leaders[1:MAX_MODES]
    points = np.array(_lhs(key, restarts, sub.lower, sub.upper))
    k = min(len(leaders), restarts)
    points[:k] = leaders[:k]
    labels = [f"LM from another optimum of the final DE population (restart {i + 1} of "
              f"{restarts})" if i < k else f"LM from a Latin-hypercube start (restart {i + 1} "
              f"of {restarts})" for i in range(restarts)]  # fmt: skip
    ends = _multistart(found.objective, sub, points, task.restart_landmarks, restarts)
    full = np.array([task.space.embed(sub.free, e, found.base) for e in ends])
    narrowed = task.restart_landmarks is not None or sub is not task.space
    out, values, best_F = _best_end(objective, task.space.box, full, labels, best, narrowed)
    landmarks = task.restart_landmarks
    info = RestartSummary(
        starts=restarts, from_population=int(k), best_F_mm=best_F,
        # How many restarts ended within 1e-4 mm of the result: few say the basin was found
        # by few starts, so a larger budget might find a lower one.
        reached_result=int(np.sum(values <= out.value + 1e-4)),
        landmarks=None if landmarks is None else len(landmarks),
    )  # fmt: skip
    return out, info


def _refits(task: StageTask, objective, best: Optimum,
            batch: int) -> tuple[Optimum, tuple[float, ...]]:  # fmt: skip
    """LM on every free parameter from the task's refit starts and from ``best`` itself, all
    at once (the convention check's multi-start, declared convention); the best end point,
    polished, replaces ``best`` if lower. Returns it and the value it replaced, if any."""
    starts = np.concatenate([task.refit_starts, np.asarray(best.x)[None]])
    k = len(task.refit_starts)
    labels = [f"LM from a uniform start (refit {i + 1} of {k})" for i in range(k)]
    labels.append(f"{best.found_by.split(', refined')[0]}, refined by a refit from it")
    ends = _multistart(objective, task.space, starts, task.restart_landmarks, batch)
    out, _, _ = _best_end(objective, task.space.box, ends, labels, best,
                          task.restart_landmarks is not None)  # fmt: skip
    if out is best:
        return best, ()
    width = task.space.upper - task.space.lower
    if np.all(np.abs(out.x - best.x) <= MODE_PARAM_FRACTION * width):
        out = replace(out, found_by=labels[-1])  # the fit's own optimum, further down
    return out, (best.value,)


#: A refit that lands within this fraction of every parameter's range of the fit has refined
#: the fit's own optimum rather than found another.
MODE_PARAM_FRACTION = 0.01


def _multistart(objective, space: ParameterSpace, starts: np.ndarray, landmarks, batch: int):
    """End points of LM from ``starts`` (in ``space``'s box) on ``objective`` (on
    ``landmarks`` only, if given), in one batch of at least ``batch`` problems: the restarts'
    size, so that the refits run the restarts' compiled program (copies of the last start
    fill it; a copy's path is its original's, so the others' are unchanged)."""
    searched = objective if landmarks is None else objective.on_landmarks(landmarks)
    k = len(starts)
    padded = np.concatenate([starts, np.repeat(starts[-1:], max(batch - k, 0), axis=0)])
    lm = LevenbergMarquardt(rtol=1e-10, atol=0.0, max_steps=RESTART_STEPS)
    return minimise_starts(searched, lm, space.box, padded).x[:k]


def _best_end(objective, box: Box, ends: np.ndarray, labels: list[str], best: Optimum,
              narrowed: bool) -> tuple[Optimum, np.ndarray, float]:  # fmt: skip
    """The end point with the lowest value of ``objective``, polished as the fit was, if it
    is lower than ``best`` by more than :data:`BETTER_BY_MM` (else ``best``); every end
    point's value; and the lowest one's value after that polish. ``narrowed``: the ends
    searched fewer landmarks or parameters, so a near one is polished before it is compared."""
    values = np.array([_value(objective, e) for e in ends])
    values = np.where(np.isfinite(values), values, np.inf)
    i = int(np.argmin(values))
    x_i, f_i = ends[i], float(values[i])
    if (narrowed and f_i < best.value + 1e-4) or f_i < best.value - BETTER_BY_MM:
        # The batch stops on a looser rule than the polish (and may have searched fewer
        # landmarks or parameters): finish the winner as the DE's best was finished.
        lm = minimise(objective, POLISH, box, x0=x_i)
        if np.isfinite(lm.value) and lm.value < f_i:
            x_i, f_i = lm.x, lm.value
    if f_i < best.value - BETTER_BY_MM:
        return Optimum(np.asarray(x_i), f_i, labels[i]), values, f_i
    return best, values, f_i
