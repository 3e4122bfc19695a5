"""The two-stage calibration: one generic "fit a stage", run for the model then the correction.

A stage's fit works on a :class:`~handeye_jax.ParameterSpace`: the free parameters of a
template, their box and maybe a Gaussian prior. DE searches some of them (all, by default),
Levenberg–Marquardt polishes all free ones from the best member, from restarts and (stage 1)
from the multi-start refits, and the lowest value any of them reaches is the stage's optimum:
the search for the best optimum is the fit's, all of it. :func:`calibrate` fits every
parameter; :func:`recalibrate` starts from a previous result (the paper's open problem:
another pen, a moved tablet, a remounted camera).

This is the only place that joins the hand–eye pieces (dataset, model, objective) to the
general optimisers. The diagnostics (:func:`handeye_jax.diagnose`) only read a result.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._core import MAX_RESTARTS, InputError, Stages
from .._jax import fast_compile, in_float64
from ..data import Dataset, Observations, check_distinct, check_population
from ..models import AbstractCorrection, AbstractModel, AbstractParametric, AffinePair, get_model
from ..optim import (
    MAX_MODES,
    Box,
    DESolution,
    LevenbergMarquardt,
    latin_hypercube,
    minimise,
    minimise_starts,
    mode_leaders,
)
from ..problem import (
    FIXED,
    AbstractObjective,
    GaussianObjective,
    L1Loss,
    LossObjective,
    ParameterSpace,
    Prior,
    PriorObjective,
    Stage1Objective,
    Stage2Objective,
    analyse_jacobian,
    chain_points,
    error_jacobian,
    errors_of,
    fitness,
    get_loss,
    height_summary,
    norms,
    put,
    resolve_names,
    spread_landmarks,
    stage2_errors,
    std_of_precision,
)
from ._payloads import (
    BoundHit,
    Convergence,
    DESummary,
    FitWarning,
    PolishSummary,
    PriorReport,
    Pull,
    Recalibration,
    Residual,
    RestartSummary,
    SignTwin,
)
from ._result import CalibrationResult, StageResult
from ._settings import Settings

#: The polish of one stage's optimum: optimistix's LM to tight tolerances.
POLISH = LevenbergMarquardt(rtol=1e-12, atol=1e-12, max_steps=1000)
#: Most LM iterations of each restart (the batch stops earlier once none improves).
RESTART_STEPS = 400
#: Above this many landmarks the restarts search on this many, spread over the touch order,
#: and only the best end point is polished on all: the restarts' cost stays bounded.
RESTART_LANDMARKS = 64
#: A restart or refit replaces the fit only when its value is lower by more than this, mm
#: (an equal one, e.g. the sign twin's, keeps the fit).
BETTER_BY_MM = 1e-9
#: A prior's parameter is flagged when the data pull it this many σ from the prior's mean.
PULL_FLAG = 3.0
#: Each landmark gives four residual scalars (x and y of both terms of the objective).
RESIDUALS_PER_LANDMARK = 4


@fast_compile
def _report(objective: AbstractObjective, x):
    # Every evaluation of a stage's objective outside the optimisers goes through this one
    # program, so each stage compiles one (not one for F and one for the residuals).
    errors = errors_of(objective, x)
    return errors, fitness(errors), norms(errors), objective(x), objective.terms(x)


def _value(objective: AbstractObjective, x) -> float:
    """The value the optimisers minimise at ``x`` (the paper's F without loss or prior)."""
    return float(_report(objective, np.asarray(x))[3])


@fast_compile
def _stage_keys(seed):
    # One small program, where PRNGKey, split and unpacking would compile several. Each stage
    # gets the DE's key and, folded from it, the key of its LM restarts.
    key1, key2 = jax.random.split(jax.random.PRNGKey(seed))
    return (key1, jax.random.fold_in(key1, 1)), (key2, jax.random.fold_in(key2, 1))


_lhs = fast_compile(latin_hypercube)


@fast_compile
def _points(model, obs):
    return chain_points(model, obs)


@fast_compile
def _centres(correction, points, centre_index: int):
    return stage2_errors(correction, points, centre_index)[1]


# -- one stage -------------------------------------------------------------------------------


def with_prior(
    objective: AbstractObjective, space: ParameterSpace, n: int, *, gaussian: bool = True
) -> AbstractObjective:
    """``objective`` (on ``space.free``) with ``space``'s prior as a ``prior`` block.

    A prior that states the noise σ of the fit it came from (a previous result's posterior)
    also turns the paper's error lengths into Gaussian errors of that σ
    (:class:`~handeye_jax.GaussianObjective`): one noise model for the prior and the data. A
    robust loss the user chose stays as it is.

    Args:
        objective: the data objective.
        space: the free parameters and their prior.
        n: the number of landmarks behind each data block.
        gaussian: whether the data may become Gaussian (False: a robust loss wraps the result).
    """
    prior = space.prior
    if prior is None:
        return objective
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


#: The hand-angle conventions ``φ = zero + sign·θh``, ``(zero deg, sign)``, that the
#: multi-start refits and the diagnostics' convention check know.
CONVENTIONS: tuple[tuple[float, int], ...] = tuple(
    (zero, sign) for sign in (1, -1) for zero in (0.0, 90.0, 180.0, 270.0)
)
#: Uniform LM starts per convention (multi-start: on the paper's data 70 % of uniform starts
#: reach the global basin, see ``benchmarks/RESULTS.md``).
REFIT_STARTS = 6


def convention_index(zero_deg: float, sign: float) -> int:
    """The position of ``(zero_deg, sign)`` in :data:`CONVENTIONS` (0 if it is not there)."""
    zero = np.array([c[0] for c in CONVENTIONS])
    signs = np.array([float(c[1]) for c in CONVENTIONS])
    return int(np.argmax((zero == float(zero_deg)) & (signs == float(sign))))


def uniform_starts(seed: int, box: Box, n: int) -> np.ndarray:
    """``n`` uniform points of ``box`` drawn by NumPy's PCG64 from ``seed`` (a negative seed
    is taken modulo 2⁶⁴)."""
    rng = np.random.default_rng(seed % 2**64)
    return rng.uniform(box.lower, box.upper, size=(n, box.d))


def refit_starts(seed: int, box: Box, rig) -> np.ndarray:
    """Stage 1's refit starts: the declared convention's share of the uniform points the
    convention check draws (the same points, so its refits never reach below the fit)."""
    k = convention_index(float(rig.angle_zero_deg), float(rig.angle_sign))
    draws = uniform_starts(seed, box, len(CONVENTIONS) * REFIT_STARTS)
    return draws[k * REFIT_STARTS : (k + 1) * REFIT_STARTS]


def _prior_report(stage: StageFit) -> PriorReport | None:
    """The prior of a stage and how far the data pulled each parameter from it.

    With ``d = θ − μ`` the fit's move from the prior mean and ``Q = Σ_prior − Σ_post`` its
    covariance when the prior is right, the pull of parameter j is Baarda's w-test of a shift
    of μ_j alone, ``(Q⁻¹d)_j/√(Q⁻¹)_jj``: standard normal for a right prior, and largest for
    the parameter that moved even when correlated ones absorb part of its move (the marginal
    ``d_j/√Q_jj``, kept as ``marginal_pull``, then blames them). ``Σ_post`` is the Gauss–Newton
    posterior ``(JᵀJ/σ² + Σ_prior⁻¹)⁻¹`` at the fit, with the noise σ of the fit the prior came
    from when the prior states it: a few new landmarks leave too few degrees of freedom to
    estimate σ (benchmarks/RESULTS.md, "Recalibration: what three touches can reach").
    """
    space = stage.space
    prior = space.prior
    if prior is None:
        return None
    e, J = (np.asarray(a) for a in _error_jacobian(stage.data, stage.x))
    idx = list(space.prior_indices())
    P_full = np.zeros((space.d, space.d))
    P_full[np.ix_(idx, idx)] = prior.precision
    if prior.data_sigma_mm is not None:
        P_post = J.T @ J / prior.data_sigma_mm**2 + P_full
    else:
        P_post = np.asarray(analyse_jacobian(e, J, space.free, ["1"] * space.d, None,
                                             P_full).precision)  # fmt: skip
    post = std_of_precision(P_post, space.free)
    Q = prior.covariance() - np.linalg.pinv(P_post, hermitian=True)[np.ix_(idx, idx)]
    w, V = np.linalg.eigh(0.5 * (Q + Q.T))
    keep = w > 1e-9 * max(float(w.max()), 1e-300)
    Q_inv = (V[:, keep] / w[keep]) @ V[:, keep].T
    d = stage.x[idx] - prior.mean
    sig_prior = prior.sigma
    out = []
    for j, name in enumerate(prior.names):
        sp, spost = float(sig_prior[j]), post[name]
        pull = (Q_inv[j] @ d) / math.sqrt(Q_inv[j, j]) if Q_inv[j, j] > 0 else 0.0
        marginal = d[j] / math.sqrt(Q[j, j]) if Q[j, j] > 0 else 0.0
        out.append(Pull(
            param=name, mean=float(prior.mean[j]), sigma=sp if math.isfinite(sp) else None,
            value=float(stage.x[idx[j]]), posterior_sigma=spost, pull=float(pull),
            marginal_pull=float(marginal),
        ))  # fmt: skip
    return PriorReport(
        source=prior.source, names=tuple(prior.names), mean=tuple(prior.mean.tolist()),
        precision=tuple(tuple(row) for row in prior.precision.tolist()),
        data_scale_mm=prior.data_scale_mm, pulls=tuple(out), data_sigma_mm=prior.data_sigma_mm,
    )  # fmt: skip


@fast_compile
def _error_jacobian(objective, x):
    return error_jacobian(objective, x)


def _stage_result(stage: StageFit, prior_report: PriorReport | None = None) -> StageResult:
    errors, (F, f1, f2), (n1, n2), value, terms = _report(stage.objective, stage.x)
    F, f1, f2 = float(F), float(f1), float(f2)
    n1, n2 = np.asarray(n1), np.asarray(n2)
    e1, e2 = np.asarray(errors.image_vs_tablet), np.asarray(errors.hand)
    residuals = tuple(
        Residual(m, tuple(e1[m].tolist()), float(n1[m]), tuple(e2[m].tolist()), float(n2[m]))
        for m in range(len(n1))
    )
    model = stage.model()
    space = stage.space
    params = {n: float(getattr(model, n)) for n in type(model).param_names}
    status = space.status()
    out = StageResult(F, f1, f2, params, residuals, stage.de, stage.polish, stage.convergence)
    extra: dict[str, Any] = {"status": status}
    if space.fixed:
        extra["fixed_source"] = {n: space.fixed_source.get(n, "template") for n in space.fixed}
    if "prior" in terms:
        extra["prior_F"] = float(terms["prior"])
    if prior_report is not None:
        extra["prior"] = prior_report
    return replace(out, **extra)


def _check_finite(stage: StageResult, name: str, source) -> None:
    """A fit whose F is NaN or infinite says the data are not a rig's: stop, do not report."""
    if not np.isfinite([stage.F, *stage.params.values()]).all():
        raise InputError(
            source, "", f"{name}'s fit is not finite (F = {stage.F} mm): check the data's values"
        )


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
        if abs(p.pull) > PULL_FLAG:
            sigma = "" if p.sigma is None else f" ± {p.sigma:.3g}"
            out.append(FitWarning(
                f"{label}: the data pull {p.param} {abs(p.pull):.1f} sigma from its prior "
                f"({prior.source}: {p.mean:.4g}{sigma}; fitted {p.value:.4g}): the prior may "
                f"be wrong for this rig; refit {p.param} (--refit) instead", "prior", p.param,
            ))  # fmt: skip
    return out


def _sign_twin(stage: StageFit) -> SignTwin | None:
    """The sign twin of a stage's fit, if its model has one and all its parameters are free."""
    cls = type(stage.space.template)
    names = [n for n in cls.sign_twin if n in stage.space.free]
    if len(names) != len(cls.sign_twin) or not names:
        return None
    idx = [stage.space.free.index(n) for n in names]
    flipped = np.array(stage.x, copy=True)
    flipped[idx] = -flipped[idx]
    return SignTwin(
        params=tuple(names), found={n: float(stage.x[i]) for n, i in zip(names, idx, strict=True)},
        F_found_mm=_value(stage.data, stage.x), F_flipped_mm=_value(stage.data, flipped),
        note="flipping the signs of " + " and ".join(names) + " together mirrors the tablet "
        "through its own plane and gives the same F",
    )  # fmt: skip


# -- both stages ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Plan:
    """What each stage fits: its parameters, what DE searches, and where the rest came from.

    Attributes:
        space1, space2: the stages' parameter spaces.
        search1, search2: the parameters DE searches in each stage.
        previous: the result the plan starts from (its file or ``None``).
        refit: the groups or parameters refitted, when starting from a previous result.
        fixed: the other parameters were held at the previous values (not given a prior).
    """

    space1: ParameterSpace
    space2: ParameterSpace
    search1: tuple[str, ...]
    search2: tuple[str, ...]
    previous: str | None = None
    refit: tuple[str, ...] = ()
    fixed: bool = False
    extra: dict[str, Any] = field(default_factory=dict)


def full_plan(dataset: Dataset, settings: Settings) -> Plan:
    """Every parameter of both stages free in its search range: the paper's calibration."""
    model_cls = get_model(settings.model)
    space1 = ParameterSpace.all_free(model_cls.nominal(), dataset.search)
    space2 = ParameterSpace.all_free(AffinePair.nominal(), dataset.search)
    return Plan(space1, space2, space1.free, space2.free)


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
    n = obs.n_landmarks
    keys1, keys2 = _stage_keys(np.int64(settings.seed))
    with_loss = _loss_wrapper(settings, n)
    subset1 = spread_landmarks(n, RESTART_LANDMARKS) if n > RESTART_LANDMARKS else None

    def build1(template, free):
        return with_loss(Stage1Objective(template, obs, free))

    task1 = StageTask(build1, plan.space1, n, plan.search1, "stage 1 DE", subset1,
                      refit_starts(settings.seed, plan.space1.box, obs.rig))  # fmt: skip
    fit1 = fit_stage(task1, settings, keys1, progress=progress)
    stage1 = _finished(fit1, "stage 1", dataset.source)
    fit2, stage2, centres = fit_correction_stage(
        obs, fit1.model(), plan.space2, plan.search2, settings, keys2,
        progress=progress, source=dataset.source,
    )  # fmt: skip
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
    )  # fmt: skip


def _checked(dataset: Dataset, plan: Plan, settings: Settings) -> Observations:
    """The dataset's observations, once the plan, the settings and the data can make a fit
    (an undetermined one is refused before any work; its warnings come with the result)."""
    model_cls = type(plan.space1.template)
    if settings.model != model_cls.name:
        raise ValueError(f"settings.model is {settings.model!r}, the plan's {model_cls.name!r}")
    check_population(dataset, settings.population)
    if not 0 <= settings.restarts <= MAX_RESTARTS:
        raise ValueError(f"restarts must be 0 to {MAX_RESTARTS:,} (got {settings.restarts})")
    obs = dataset.observations()
    check_determined(obs.n_landmarks, plan.space1, "stage 1", dataset.source)
    check_determined(obs.n_landmarks, plan.space2, "stage 2", dataset.source)
    check_distinct(dataset.tablet_px, dataset.source)
    return obs


def _finished(stage: StageFit, name: str, source: str | Path | None) -> StageResult:
    """A stage's fit as numbers, once it is finite (``source`` names the data if not)."""
    out = _stage_result(stage, _prior_report(stage))
    _check_finite(out, name, source)
    return out


def fit_correction_stage(
    obs: Observations,
    model: AbstractModel,
    space2: ParameterSpace,
    search2: Sequence[str],
    settings: Settings,
    keys2: tuple[jax.Array, jax.Array],
    *,
    progress: bool = False,
    source: str | Path | None = None,
) -> tuple[StageFit, StageResult, np.ndarray]:
    """Stage 2 on the chain points of a stage-1 ``model``: its fit, its result and its
    centres of rotation (rows: A1, A2), mm. ``source`` names the data in an error."""
    n = obs.n_landmarks
    points = _points(model, obs)
    with_loss = _loss_wrapper(settings, n)
    subset = None
    if n > RESTART_LANDMARKS:
        subset = spread_landmarks(n, RESTART_LANDMARKS, include=obs.centre_index)

    def build2(template, free):
        return with_loss(Stage2Objective(template, points, obs.centre_index, free))

    task = StageTask(build2, space2, n, tuple(search2), "stage 2 DE", subset)
    fit2 = fit_stage(task, settings, keys2, progress=progress)
    stage2 = _finished(fit2, "stage 2", source)
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


def _widened(cls, search, names, prior: Prior | None, template) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = cls.search_bounds(search)
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


def recalibration_plan(
    dataset: Dataset,
    previous: CalibrationResult,
    refit: Sequence[str],
    *,
    fix: bool = False,
    source: str = "previous result",
) -> Plan:
    """Stage 1 with the ``refit`` groups (or parameters) searched afresh and the others taken
    from ``previous``: as its posterior for a prior, or (``fix``) held at its values. Stage 2
    starts from the previous correction, with its posterior as the prior (or held, ``fix``).
    """
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
    if fix:
        lo, hi = _widened(model_cls, dataset.search, refit_names, None, template1)
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
        lo, hi = _widened(model_cls, dataset.search, free1, prior1, template1)
        space1 = ParameterSpace(template1, free1, lo, hi, prior1, was_fixed)
        prior2 = _previous_prior(previous, "stage2", prev_free2, source)
        if prior2 is not None:
            prior2 = replace(prior2, data_scale_mm=scale2)
        free2 = tuple(prev_free2)
        lo2, hi2 = _widened(AffinePair, dataset.search, free2, prior2, template2)
        space2 = ParameterSpace(template2, free2, lo2, hi2, prior2)
    return Plan(space1, space2, refit_names, (), source, tuple(refit), fix)


def recalibrate(
    dataset: Dataset,
    previous: CalibrationResult,
    refit: Sequence[str],
    settings: Settings | None = None,
    *,
    fix: bool = False,
    source: str | Path | None = None,
    progress: bool = False,
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
    """
    if settings is None:
        settings = previous.settings
    if settings.model != previous.model_name:
        raise ValueError(f"the previous result is of model {previous.model_name!r}, settings "
                         f"say {settings.model!r}")  # fmt: skip
    source = str(source) if source is not None else f"previous result ({previous.dataset_name})"
    with jax.enable_x64(True):
        plan = recalibration_plan(dataset, previous, refit, fix=fix, source=source)
    return fit(dataset, plan, settings, progress=progress)


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
    fit2, _, centres = fit_correction_stage(dataset.observations(), model, space2, space2.free,
                                            settings, keys2, source=dataset.source)  # fmt: skip
    return fit2.model(), centres


# -- what the diagnostics read of a result -------------------------------------------------


def _prior_of(report: PriorReport | None) -> Prior | None:
    if report is None:
        return None
    return Prior(report.names, report.mean, report.precision, report.source, report.data_scale_mm,
                 report.data_sigma_mm)  # fmt: skip


def _spaces_of(result: CalibrationResult, search: dict) -> Stages[ParameterSpace]:
    """The stages' parameter spaces of a result read from a file (its boxes: the search
    ranges, widened to hold the fit and its priors)."""
    spaces = []
    for template, stage in ((result.model, result.stage1),
                            (result.correction, result.stage2)):  # fmt: skip
        cls = type(template)
        free = tuple(n for n in cls.param_names if n in stage.free())
        prior = _prior_of(stage.prior)
        lo, hi = _widened(cls, search, free, prior, template)
        spaces.append(ParameterSpace(template, free, lo, hi, prior, stage.fixed_source))
    return Stages(*spaces)


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
        spaces = _spaces_of(result, search or {})
        xs = Stages(*(np.array([s.params[nm] for nm in sp.free])
                      for sp, s in ((spaces.stage1, result.stage1),
                                    (spaces.stage2, result.stage2))))  # fmt: skip
        populations = Stages(None, None)
    # Gaussian data under a prior that states its noise, unless a robust loss was chosen: as
    # the fit's objectives (with_prior).
    gaussian = isinstance(get_loss(result.settings.loss, result.settings.loss_scale_mm), L1Loss)
    sp1, sp2 = spaces.stage1, spaces.stage2
    s1 = with_prior(Stage1Objective(sp1.template, obs, sp1.free), sp1, n, gaussian=gaussian)
    points = _points(put(sp1.template, sp1.free, jnp.asarray(xs.stage1)), obs)
    s2 = Stage2Objective(sp2.template, points, obs.centre_index, sp2.free)
    s2 = with_prior(s2, sp2, n, gaussian=gaussian)
    return Stages(FittedStage(sp1, s1, xs.stage1, populations.stage1),
                  FittedStage(sp2, s2, xs.stage2, populations.stage2))  # fmt: skip


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
