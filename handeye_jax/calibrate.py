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
from ._x64 import in_float64
from .dataset import Dataset, check_min_landmarks, check_population
from .diagnostics import bound_hits, diagnose
from .errors import InputError
from .losses import L1Loss, LossObjective, get_loss
from .models import AbstractModel, AbstractParametric, AffinePair, get_model
from .objective import (
    AbstractObjective,
    Stage1Objective,
    Stage2Objective,
    chain_points,
    fitness,
    norms,
    stage2_errors,
)
from .optim import differential_evolution, levenberg_marquardt
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
        polish: run Levenberg–Marquardt from the best DE member of each stage.
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
    loss: str = "l1"
    loss_scale_mm: float = 1.0
    diagnostics: bool = True


@_xla.fast_compile
def _report(objective: AbstractObjective, x):
    # Every evaluation of a stage's objective outside the optimisers goes through this one
    # program, so each stage compiles one (not one for F and one for the residuals).
    errors = objective.errors(x)
    return errors, fitness(errors), norms(errors), objective(x)


def _value(objective: AbstractObjective, x) -> float:
    """The value the optimisers minimise at ``x`` (with the default loss, F in mm)."""
    return float(_report(objective, np.asarray(x))[3])


@_xla.fast_compile
def _stage_keys(seed):
    # One small program, where PRNGKey, split and unpacking the pair would compile three.
    key1, key2 = jax.random.split(jax.random.PRNGKey(seed))
    return key1, key2


@_xla.fast_compile
def _points(model_cls, x, obs):
    return chain_points(model_cls.from_vector(x), obs)


@_xla.fast_compile
def _centres(x, points, centre_index: int):
    return stage2_errors(AffinePair.from_vector(x), points, centre_index)[1]


def _optimise(
    objective: AbstractObjective,
    cls: type[AbstractParametric],
    search: dict[str, tuple[float, float]],
    key: jax.Array,
    settings: Settings,
    progress: bool,
    label: str,
) -> tuple[
    np.ndarray, dict[str, Any], dict[str, Any], dict[str, list[float]], dict[str, float], tuple
]:
    """DE then box-constrained LM on one objective; LM is kept only if it lowers F.

    Returns the optimum, DE and LM summaries, the convergence history, timings (s) and the
    final DE population with its fitness.
    """
    lower, upper = cls.search_bounds(search)
    t0 = time.perf_counter()
    de = differential_evolution(
        objective, lower, upper, key=key, population=settings.population,
        generations=settings.generations, crossover=settings.crossover,
        mutation=settings.mutation, tol=settings.tol, early_stop=settings.early_stop,
        progress=progress, desc=label,
    )  # fmt: skip
    t1 = time.perf_counter()
    x = de.x
    polish: dict[str, Any] = {"ran": settings.polish, "accepted": False, "F_before": de.f}
    if settings.polish:
        lm = levenberg_marquardt(objective.residuals, de.x, lower, upper)
        f_lm = _value(objective, lm.x)
        accepted = bool(np.isfinite(f_lm) and f_lm < de.f)
        polish.update(
            accepted=accepted, F_after=f_lm, steps=lm.steps, solver_converged=lm.solver_ok,
        )  # fmt: skip
        if accepted:
            x = lm.x
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


@in_float64
def calibrate(
    dataset: Dataset, settings: Settings = Settings(), *, progress: bool = False
) -> CalibrationResult:
    """Fit the stage-1 model and the stage-2 correction to a dataset.

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
    obs = dataset.observations()
    key1, key2 = _stage_keys(np.int64(settings.seed))

    loss = get_loss(settings.loss, settings.loss_scale_mm)

    def with_loss(objective):  # the paper's F stays the plain objective (and its compiled code)
        if isinstance(loss, L1Loss):
            return objective
        return LossObjective(objective, loss, jnp.ones(obs.n_landmarks))

    paper1 = Stage1Objective(model_cls, obs)
    obj1 = with_loss(paper1)
    x1, de1, pol1, conv1, t1, pop1 = _optimise(
        obj1, model_cls, dataset.search, key1, settings, progress, "stage 1 DE"
    )
    stage1 = _stage_result(paper1, x1, model_cls, de1, pol1, conv1)
    _check_finite(stage1, "stage 1", dataset.source)

    points = _points(model_cls, np.asarray(x1), obs)
    paper2 = Stage2Objective(AffinePair, points, obs.centre_index)
    obj2 = with_loss(paper2)
    x2, de2, pol2, conv2, t2, pop2 = _optimise(
        obj2, AffinePair, dataset.search, key2, settings, progress, "stage 2 DE"
    )
    stage2 = _stage_result(paper2, x2, AffinePair, de2, pol2, conv2)
    _check_finite(stage2, "stage 2", dataset.source)
    centres = _centres(np.asarray(x2), points, obs.centre_index)

    warnings = fit_warnings(stage1, stage2)
    warnings += bound_warnings(stage1.params, model_cls, dataset.search) + bound_warnings(
        stage2.params, AffinePair, dataset.search
    )
    diagnostics: dict[str, Any] = {}
    t_diag = time.perf_counter()
    if settings.diagnostics:
        diagnostics = diagnose(
            model_cls=model_cls, correction_cls=AffinePair, obs=obs, loss=loss,
            loss_scale_mm=settings.loss_scale_mm, x=(x1, x2),
            stage_results=(stage1, stage2), populations=(pop1, pop2), search=dataset.search,
            seed=settings.seed,
        )  # fmt: skip
        if diagnostics["convention"]["warning"]:
            warnings.append(diagnostics["convention"]["warning"])
    timings = {
        "stage1_de": t1["de"], "stage1_polish": t1["polish"],
        "stage2_de": t2["de"], "stage2_polish": t2["polish"],
        "diagnostics": time.perf_counter() - t_diag,
        "total": time.perf_counter() - t_start,
    }  # fmt: skip
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
    _, key2 = _stage_keys(np.int64(settings.seed))
    points = _points(type(model), model.to_vector(), obs)
    objective = Stage2Objective(AffinePair, points, obs.centre_index)
    x2, *_ = _optimise(objective, AffinePair, dataset.search, key2, settings, False, "stage 2")
    centres = _centres(np.asarray(x2), points, obs.centre_index)
    return AffinePair.from_vector(jnp.asarray(x2)), np.asarray(centres)
