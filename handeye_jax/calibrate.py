"""The two-stage calibration: DE then LM on F1st for the model, then on F2nd for the correction.

This is the only place that joins the hand–eye pieces (dataset, model, objective) to the
general optimisers.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from . import _xla
from ._objective import (
    AbstractObjective,
    LossObjective,
    Stage1Objective,
    Stage2Objective,
    chain_points,
    errors_of,
    fitness,
    norms,
    spread_landmarks,
    stage2_errors,
)
from ._validate import MAX_RESTARTS
from ._x64 import in_float64
from .dataset import Dataset, check_min_landmarks, check_population
from .diagnostics import MAX_MODES, bound_hits, diagnose, mode_leaders
from .errors import InputError
from .losses import L1Loss, get_loss
from .models import AbstractModel, AbstractParametric, AffinePair, get_model
from .optim import differential_evolution, levenberg_marquardt, levenberg_marquardt_starts
from .optim.de import latin_hypercube
from .refits import REFIT_LANDMARKS
from .result import CalibrationResult, StageResult, observations_to_dict, rig_to_dict


@dataclass(frozen=True)
class Settings:
    """How to calibrate.

    Attributes:
        model: stage-1 model name, ``"htm"`` or ``"dh"``.
        seed: PRNG seed; the same seed gives the same result bit for bit.
        population: DE population N (both stages).
        generations: most DE generations G (both stages).
        early_stop: stop DE when the population's fitness spread is below ``tol``.
        tol: relative spread for the early stop, ``std(F) <= tol·|mean(F)|``.
        crossover: DE's CR. mutation: DE's F (differential weight).
        polish: run Levenberg–Marquardt from the best DE member of each stage, and from the
            ``restarts``; the lowest F any of them reaches is the stage's result.
        restarts: LM starts in each stage besides the best DE member: the best member of each
            other distinct optimum in the final DE population, the rest points of a Latin
            hypercube of the search box; 0 runs none. The DE alone can settle in a basin that
            is not the lowest (6 of 50 ``paper`` twins with these DE settings,
            ``benchmarks/miss_rate.py``).
        loss: ``"l1"`` (the paper's mean error length), ``"huber"`` or ``"cauchy"``
            (:mod:`handeye_jax.losses`); a robust loss limits the pull of outlier landmarks.
        loss_scale_mm: the robust loss's scale, mm; landmarks with an error above
            ``OUTLIER_FACTOR`` (3) times it are flagged as outliers, whatever the loss.
        diagnostics: compute the result's ``diagnostics`` (uncertainty, identifiability,
            optima, leave-one-out, convention check); about a second more.

    The paper's settings are ``population=10000, generations=10000, early_stop=False``; the
    defaults reach the same optimum on the paper's data in seconds.
    """

    model: str = "htm"
    seed: int = 1
    population: int = 500
    generations: int = 3000
    early_stop: bool = True
    tol: float = 1e-3
    crossover: float = 0.9
    mutation: float = 0.5
    polish: bool = True
    restarts: int = 32
    loss: str = "l1"
    loss_scale_mm: float = 1.0
    diagnostics: bool = True


@_xla.fast_compile
def _report(objective: AbstractObjective, x):
    # Every evaluation of a stage's objective outside the optimisers goes through this one
    # program, so each stage compiles one (not one for F and one for the residuals).
    errors = errors_of(objective, x)
    return errors, fitness(errors), norms(errors), objective(x)


def _value(objective: AbstractObjective, x) -> float:
    """The value the optimisers minimise at ``x`` (with the default loss, F in mm)."""
    return float(_report(objective, np.asarray(x))[3])


@_xla.fast_compile
def _stage_keys(seed):
    # One small program, where PRNGKey, split and unpacking would compile several. Each stage
    # gets the DE's key and, folded from it, the key of its LM restarts.
    key1, key2 = jax.random.split(jax.random.PRNGKey(seed))
    return (key1, jax.random.fold_in(key1, 1)), (key2, jax.random.fold_in(key2, 1))


#: Most LM iterations of each restart (the batch stops earlier once none improves).
RESTART_STEPS = 400
#: Above this many landmarks the restarts search on this many, spread over the touch order,
#: and only the best end point is polished on all: the restarts' cost stays bounded.
RESTART_LANDMARKS = 64
#: A restart or refit replaces the fit only when its F is lower by more than this, mm (an
#: equal F, e.g. the sign twin's, keeps the fit).
BETTER_BY_MM = 1e-9

_lhs = _xla.fast_compile(latin_hypercube)


@_xla.fast_compile
def _points(model_cls, x, obs):
    return chain_points(model_cls.from_vector(x), obs)


@_xla.fast_compile
def _centres(x, points, centre_index: int):
    return stage2_errors(AffinePair.from_vector(x), points, centre_index)[1]


def _restart_starts(
    key: jax.Array, lower: np.ndarray, upper: np.ndarray, leaders: np.ndarray, restarts: int
) -> np.ndarray:
    """``restarts`` LM starts: the other optima's best members first, then hypercube points."""
    points = np.array(_lhs(key, restarts, np.asarray(lower, float), np.asarray(upper, float)))
    k = min(len(leaders), restarts)
    points[:k] = leaders[:k]
    return points


def _optimise(
    objective: AbstractObjective,
    cls: type[AbstractParametric],
    search: dict[str, tuple[float, float]],
    keys: tuple[jax.Array, jax.Array],
    settings: Settings,
    progress: bool,
    label: str,
    restart_landmarks: np.ndarray | None = None,
) -> tuple[
    np.ndarray, dict[str, Any], dict[str, Any], dict[str, list[float]], dict[str, float], tuple
]:
    """DE, then box-constrained LM from the best member and from ``settings.restarts`` other
    starts; the lowest F found is the optimum (LM is kept only if it lowers F). The restarts
    search on the landmarks ``restart_landmarks`` alone if given.

    Returns the optimum, DE and LM summaries (the LM summary's ``found_by`` says which start
    led to the optimum), the convergence history, timings (s) and the final DE population
    with its fitness.
    """
    key, restart_key = keys
    lower, upper = cls.search_bounds(search)
    t0 = time.perf_counter()
    de = differential_evolution(
        objective, lower, upper, key=key, population=settings.population,
        generations=settings.generations, crossover=settings.crossover,
        mutation=settings.mutation, tol=settings.tol, early_stop=settings.early_stop,
        progress=progress, desc=label,
    )  # fmt: skip
    t1 = time.perf_counter()
    x, f, found_by = de.x, de.f, "DE"
    polish: dict[str, Any] = {"ran": settings.polish, "accepted": False, "F_before": de.f}
    if settings.polish:
        lm = levenberg_marquardt(objective.residuals, de.x, lower, upper)
        f_lm = _value(objective, lm.x)
        polish.update(steps=lm.steps, solver_converged=lm.solver_ok)
        if np.isfinite(f_lm) and f_lm < f:
            x, f, found_by = lm.x, f_lm, "DE + LM"
        if settings.restarts > 0:
            searched = objective
            if restart_landmarks is not None:
                searched = objective.on_landmarks(restart_landmarks)
            x, f, found_by, polish["restarts"] = _restarts(
                objective, searched, de, lower, upper, restart_key, settings.restarts,
                (x, f, found_by),
            )  # fmt: skip
            if restart_landmarks is not None:
                polish["restarts"]["landmarks"] = len(restart_landmarks)
        polish.update(accepted=bool(f < de.f), F_after=f)
    polish["found_by"] = found_by
    t2 = time.perf_counter()
    de_info = {
        "F": de.f, "generations": de.generations, "evaluations": de.evaluations,
        "converged": de.converged,
    }  # fmt: skip
    convergence = {
        "best_F": [float(v) for v in de.best_history],
        "median_F": [float(v) for v in de.median_history],
        "median_generation": [int(g) for g in de.median_generations],
    }
    timings = {"de": t1 - t0, "polish": t2 - t1}
    return x, de_info, polish, convergence, timings, (de.population, de.fitness)


def _restarts(objective, search_objective, de, lower, upper, key, restarts, fit):
    """LM on ``search_objective`` from the final population's other optima and from hypercube
    points, all at once; the end point with the lowest ``objective``, polished on it, replaces
    ``fit = (x, F, found_by)`` if lower."""
    x, f, found_by = fit
    leaders = mode_leaders(de.population, de.fitness, lower, upper)[0][1:MAX_MODES]
    starts = _restart_starts(key, lower, upper, leaders, restarts)
    ends, _ = levenberg_marquardt_starts(
        search_objective.residuals, starts, lower, upper, max_steps=RESTART_STEPS
    )
    values = np.array([_value(objective, e) for e in ends])
    values = np.where(np.isfinite(values), values, np.inf)
    i = int(np.argmin(values))
    x_i, f_i = ends[i], float(values[i])
    if (search_objective is not objective and f_i < f + 1e-4) or f_i < f - BETTER_BY_MM:
        # The batch stops on a looser rule than the polish (and may have searched fewer
        # landmarks): finish the winner as the DE's best was finished.
        lm = levenberg_marquardt(objective.residuals, x_i, lower, upper)
        f_lm = _value(objective, lm.x)
        if np.isfinite(f_lm) and f_lm < f_i:
            x_i, f_i = lm.x, f_lm
    if f_i < f - BETTER_BY_MM:
        x, f = x_i, f_i
        k = min(len(leaders), restarts)
        found_by = (
            f"LM from another optimum of the final DE population (restart {i + 1} of {restarts})"
            if i < k
            else f"LM from a Latin-hypercube start (restart {i + 1} of {restarts})"
        )
    info = {
        "starts": restarts, "from_population": int(min(len(leaders), restarts)),
        "best_F": f_i,
        # How many restarts ended within 1e-4 mm of the result: few say the basin was found
        # by few starts, so a larger budget might find a lower one.
        "reached_result": int(np.sum(values <= f + 1e-4)),
    }  # fmt: skip
    return x, f, found_by, info


def _stage_result(objective, x, cls, de_info, polish, convergence) -> StageResult:
    errors, (F, f1, f2), (n1, n2), _ = _report(objective, np.asarray(x))
    F, f1, f2 = float(F), float(f1), float(f2)
    n1, n2 = np.asarray(n1), np.asarray(n2)
    e1, e2 = np.asarray(errors.image_vs_tablet), np.asarray(errors.hand)
    residuals = [
        {
            "m": m,
            "image_vs_tablet_xy_mm": e1[m].tolist(),
            "image_vs_tablet_mm": float(n1[m]),
            "hand_xy_mm": e2[m].tolist(),
            "hand_mm": float(n2[m]),
        }  # fmt: skip
        for m in range(len(n1))
    ]
    params = dict(zip(cls.param_names, (float(v) for v in x), strict=True))
    return StageResult(F, f1, f2, params, residuals, de_info, polish, convergence)


def _check_finite(stage: StageResult, name: str, source) -> None:
    """A fit whose F is NaN or infinite says the data are not a rig's: stop, do not report."""
    if not np.isfinite([stage.F, *stage.params.values()]).all():
        raise InputError(
            source, "", f"{name}'s fit is not finite (F = {stage.F} mm): check the data's values"
        )


def bound_warnings(
    params: dict[str, float], cls: type[AbstractParametric], search: dict
) -> list[str]:
    """One warning per parameter sitting on a bound of its search range."""
    out = []
    for hit in bound_hits(params, cls, search):
        name, u = hit["param"], "" if hit["unit"] == "1" else f" {hit['unit']}"
        (lo, hi), (wlo, whi) = hit["range"], hit["widen_to"]
        out.append(
            f"{name} = {hit['value']:.4g}{u} is on the {hit['side']} bound of its search range "
            f"[{lo:g}, {hi:g}]; the optimum may lie outside it: widen it in the dataset's "
            f"[search] table, e.g. {name} = [{wlo:g}, {whi:g}]"
        )
    return out


#: A fit whose F is above this, mm, is no rig's: the paper's is 0.36 mm.
F_DOES_NOT_FIT_MM = 100.0


def fit_warnings(stage1: StageResult, stage2: StageResult) -> list[str]:
    """A plain warning when F is so large that the data cannot be a rig's."""
    F = max(stage1.F, stage2.F)
    if F <= F_DOES_NOT_FIT_MM:
        return []
    return [
        f"the data do not fit: F = {F:.4g} mm, more than {F_DOES_NOT_FIT_MM:g} mm (a working "
        "rig fits to about 1 mm); do not use this result. Check the dataset's units (mm, deg, "
        "px), [tablet] ppi and scale, [camera], and the hand-angle convention"
    ]


def _sign_twin(objective, cls, x) -> dict[str, Any]:
    names = getattr(cls, "sign_twin", ())
    if not names:
        return {}
    idx = [cls.param_names.index(n) for n in names]
    flipped = np.array(x, copy=True)
    flipped[idx] = -flipped[idx]
    return {
        "params": list(names),
        "found": {n: float(x[i]) for n, i in zip(names, idx, strict=True)},
        "F_found": _value(objective, x),
        "F_flipped": _value(objective, flipped),
        "note": "flipping the signs of " + " and ".join(names) + " together mirrors the "
        "tablet through its own plane and gives the same F",
    }


#: How many times a calibration takes a better optimum from its own diagnostics (each time
#: it refits stage 2 and runs the diagnostics again).
MAX_ADOPTIONS = 2


def _better_refit(objective, diagnostics: dict, f: float, bounds, searched_fewer: bool):
    """The diagnostics' multi-start refit (declared convention) with the lowest value of
    ``objective``, if it is lower than ``f`` by more than :data:`BETTER_BY_MM`, as ``(x,
    value, elsewhere)`` (``elsewhere``: it is another optimum, not the fit's own, refined);
    else None.

    ``searched_fewer``: the refits searched on fewer landmarks than ``objective`` has, so
    their end points are polished on all before they are compared (the best one of those
    that differ from the fit).
    """
    found = []
    for mode in diagnostics["stage1"].get("local_optima", []):
        x_r = np.array(list(mode["params"].values()))
        found.append((_value(objective, x_r), x_r, bool(mode["differs_from_fit"])))
    found = sorted((c for c in found if np.isfinite(c[0])), key=lambda c: c[0])
    elsewhere = [c for c in found if c[2]]
    if searched_fewer and elsewhere:
        f_r, x_r, _ = elsewhere[0]
        lm = levenberg_marquardt(objective.residuals, x_r, *bounds)
        f_lm = _value(objective, lm.x)
        found.append((f_lm, lm.x, True) if np.isfinite(f_lm) and f_lm < f_r else elsewhere[0])
        found.sort(key=lambda c: c[0])
    if found and found[0][0] < f - BETTER_BY_MM:
        return found[0][1], found[0][0], found[0][2]
    return None


@in_float64
def calibrate(
    dataset: Dataset, settings: Settings = Settings(), *, progress: bool = False
) -> CalibrationResult:
    """Fit the stage-1 model and the stage-2 correction to a dataset.

    Each stage's optimum is the lowest F found by the DE, the LM polish and the LM restarts.
    With diagnostics on, a multi-start refit of stage 1 that reaches a lower F than that
    becomes the result (stage 2 and the diagnostics are then run again on it); the stage's
    ``polish.found_by`` says which search found the optimum.

    Args:
        dataset: a validated dataset (see :func:`handeye_jax.dataset.load_dataset`).
        settings: model, seed and optimiser settings.
        progress: show progress bars on stderr.
    """
    t_start = time.perf_counter()
    model_cls = get_model(settings.model)
    n_params = max(len(model_cls.param_names), len(AffinePair.param_names))
    check_min_landmarks(dataset, n_params, dataset.source)
    check_population(dataset, settings.population)
    if not 0 <= settings.restarts <= MAX_RESTARTS:
        raise ValueError(f"restarts must be 0 to {MAX_RESTARTS:,} (got {settings.restarts})")
    obs = dataset.observations()
    keys1, keys2 = _stage_keys(np.int64(settings.seed))

    loss = get_loss(settings.loss, settings.loss_scale_mm)

    def with_loss(objective):  # the paper's F stays the plain objective (and its compiled code)
        if isinstance(loss, L1Loss):
            return objective
        return LossObjective(objective, loss, jnp.ones(obs.n_landmarks))

    n = obs.n_landmarks
    subset1 = subset2 = None
    if n > RESTART_LANDMARKS:
        subset1 = spread_landmarks(n, RESTART_LANDMARKS)
        subset2 = spread_landmarks(n, RESTART_LANDMARKS, include=obs.centre_index)
    paper1 = Stage1Objective(model_cls, obs)
    obj1 = with_loss(paper1)
    bounds1 = model_cls.search_bounds(dataset.search)
    x1, de1, pol1, conv1, t1, pop1 = _optimise(
        obj1, model_cls, dataset.search, keys1, settings, progress, "stage 1 DE", subset1
    )

    def fit_stage2(x1):
        points = _points(model_cls, np.asarray(x1), obs)
        paper2 = Stage2Objective(AffinePair, points, obs.centre_index)
        x2, de2, pol2, conv2, t2, pop2 = _optimise(
            with_loss(paper2), AffinePair, dataset.search, keys2, settings, progress,
            "stage 2 DE", subset2,
        )  # fmt: skip
        stage2 = _stage_result(paper2, x2, AffinePair, de2, pol2, conv2)
        _check_finite(stage2, "stage 2", dataset.source)
        return x2, stage2, t2, pop2, _centres(np.asarray(x2), points, obs.centre_index)

    stage1 = _stage_result(paper1, x1, model_cls, de1, pol1, conv1)
    _check_finite(stage1, "stage 1", dataset.source)
    x2, stage2, t2, pop2, centres = fit_stage2(x1)

    diagnostics: dict[str, Any] = {}
    t_diag = time.perf_counter()
    t_restage = 0.0
    if settings.diagnostics:
        for adoption in range(MAX_ADOPTIONS + 1):
            diagnostics = diagnose(
                model_cls=model_cls, correction_cls=AffinePair, obs=obs, loss=loss,
                loss_scale_mm=settings.loss_scale_mm, x=(x1, x2),
                stage_results=(stage1, stage2), populations=(pop1, pop2),
                search=dataset.search, seed=settings.seed,
            )  # fmt: skip
            better = _better_refit(obj1, diagnostics, _value(obj1, x1), bounds1,
                                   n > REFIT_LANDMARKS)  # fmt: skip
            if better is None or adoption == MAX_ADOPTIONS:
                break
            # A refit reached a lower F than the fit (another optimum, or the fit's own one
            # further down): take it, refit stage 2 on its points, and run the diagnostics
            # again, from it.
            t0 = time.perf_counter()
            x_r, f_r, elsewhere = better
            lm = levenberg_marquardt(obj1.residuals, x_r, *bounds1)
            f_lm = _value(obj1, lm.x)
            if np.isfinite(f_lm) and f_lm < f_r:
                x_r, f_r = lm.x, f_lm
            pol1 = {
                **pol1, "accepted": bool(f_r < de1["F"]), "F_after": f_r,
                "found_by": "diagnostics multi-start refit" if elsewhere else
                f"{pol1['found_by'].split(', refined')[0]}, refined by the diagnostics' refit "
                "from it",
                "replaced_F": [*pol1.get("replaced_F", []), _value(obj1, x1)],
            }  # fmt: skip
            x1 = x_r
            stage1 = _stage_result(paper1, x1, model_cls, de1, pol1, conv1)
            _check_finite(stage1, "stage 1", dataset.source)
            x2, stage2, t2, pop2, centres = fit_stage2(x1)
            t_restage += time.perf_counter() - t0

    warnings = fit_warnings(stage1, stage2)
    warnings += bound_warnings(stage1.params, model_cls, dataset.search) + bound_warnings(
        stage2.params, AffinePair, dataset.search
    )
    if diagnostics and diagnostics["convention"]["warning"]:
        warnings.append(diagnostics["convention"]["warning"])
    timings = {
        "stage1_de": t1["de"], "stage1_polish": t1["polish"],
        "stage2_de": t2["de"], "stage2_polish": t2["polish"],
        "diagnostics": time.perf_counter() - t_diag - t_restage,
        "total": time.perf_counter() - t_start,
    }  # fmt: skip
    if t_restage:
        timings["refit_adoption"] = t_restage
    return CalibrationResult(
        model=settings.model,
        seed=settings.seed,
        settings=asdict(settings),
        dataset=dataset.name,
        rig=rig_to_dict(obs.rig),
        stage1=stage1,
        stage2=stage2,
        centre_index=obs.centre_index,
        centres_mm=np.asarray(centres).tolist(),
        timings_s=timings,
        sign_twin=_sign_twin(paper1, model_cls, x1),
        warnings=warnings,
        diagnostics=diagnostics,
        observations=observations_to_dict(dataset),
    )


@in_float64
def fit_correction(
    dataset: Dataset, model: AbstractModel, settings: Settings = Settings()
) -> tuple[AffinePair, np.ndarray]:
    """Stage 2 alone: fit the affine correction to a dataset with a given stage-1 model.

    With the true model (on synthetic data) this is the oracle's stage 2. The DE key is the
    one :func:`calibrate` uses for its stage 2, so the two are comparable seed for seed.

    Returns:
        The fitted correction and its centres of rotation (rows: A1, A2), mm.
    """
    obs = dataset.observations()
    _, keys2 = _stage_keys(np.int64(settings.seed))
    points = _points(type(model), model.to_vector(), obs)
    objective = Stage2Objective(AffinePair, points, obs.centre_index)
    subset = None
    if obs.n_landmarks > RESTART_LANDMARKS:
        subset = spread_landmarks(obs.n_landmarks, RESTART_LANDMARKS, include=obs.centre_index)
    x2, *_ = _optimise(
        objective, AffinePair, dataset.search, keys2, settings, False, "stage 2", subset
    )
    centres = _centres(np.asarray(x2), points, obs.centre_index)
    return AffinePair.from_vector(jnp.asarray(x2)), np.asarray(centres)
