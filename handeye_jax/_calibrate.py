"""The two-stage calibration: one generic "fit a stage", run for the model then the correction.

A stage's fit works on a :class:`~handeye_jax.ParameterSpace`: the free parameters of a
template, their box and maybe a Gaussian prior. DE searches some of them (all, by default),
Levenberg–Marquardt polishes all free ones from the best member and from restarts, and the
lowest value any of them reaches is the stage's optimum. :func:`calibrate` fits every
parameter; :func:`recalibrate` starts from a previous result (the paper's open problem:
another pen, a moved tablet, a remounted camera).

This is the only place that joins the hand–eye pieces (dataset, model, objective) to the
general optimisers. The diagnostics are a separate step (:func:`handeye_jax.diagnose`).
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

from . import _xla
from ._dataset import Dataset, check_distinct, check_population
from ._diagnostics import MAX_MODES, bound_hits, mode_leaders
from ._errors import InputError
from ._identifiability import analyse_jacobian, error_jacobian, std_of_precision
from ._losses import L1Loss, get_loss
from ._objective import (
    AbstractObjective,
    GaussianObjective,
    LossObjective,
    PriorObjective,
    Stage1Objective,
    Stage2Objective,
    chain_points,
    errors_of,
    fitness,
    height_summary,
    norms,
    spread_landmarks,
    stage2_errors,
)
from ._observations import Observations
from ._params import FIXED, ParameterSpace, Prior, put, resolve_names
from ._refits import REFIT_LANDMARKS
from ._result import CalibrationResult, StageResult
from ._rig_change import check_rig
from ._scope import capture_scope
from ._settings import Settings
from ._validate import MAX_RESTARTS
from ._x64 import in_float64
from .models import AbstractCorrection, AbstractModel, AbstractParametric, AffinePair, get_model
from .optim import (
    Bounds,
    LevenbergMarquardt,
    latin_hypercube,
    minimise,
    minimise_starts,
)

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


@_xla.fast_compile
def _report(objective: AbstractObjective, x):
    # Every evaluation of a stage's objective outside the optimisers goes through this one
    # program, so each stage compiles one (not one for F and one for the residuals).
    errors = errors_of(objective, x)
    return errors, fitness(errors), norms(errors), objective(x), objective.terms(x)


def _value(objective: AbstractObjective, x) -> float:
    """The value the optimisers minimise at ``x`` (the paper's F without loss or prior)."""
    return float(_report(objective, np.asarray(x))[3])


@_xla.fast_compile
def _stage_keys(seed):
    # One small program, where PRNGKey, split and unpacking would compile several. Each stage
    # gets the DE's key and, folded from it, the key of its LM restarts.
    key1, key2 = jax.random.split(jax.random.PRNGKey(seed))
    return (key1, jax.random.fold_in(key1, 1)), (key2, jax.random.fold_in(key2, 1))


_lhs = _xla.fast_compile(latin_hypercube)


@_xla.fast_compile
def _points(model, obs):
    return chain_points(model, obs)


@_xla.fast_compile
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
class StageFit:
    """One stage's optimum in the fit's own terms (before it becomes a :class:`StageResult`).

    Attributes:
        space: the stage's parameters.
        objective: what the stage minimised (loss and prior included), on ``space.free``.
        data: the paper's objective on ``space.free`` (the stage's F).
        x: the optimum's free parameters.
        de, polish, convergence: the DE and LM summaries and the DE's history.
        timings: seconds of DE and of the polish.
        population: the final DE population and its values (in the searched parameters) and
            the names searched, for the diagnostics.
    """

    space: ParameterSpace
    objective: AbstractObjective
    data: AbstractObjective
    x: np.ndarray
    de: dict[str, Any]
    polish: dict[str, Any]
    convergence: dict[str, list[float]]
    timings: dict[str, float]
    population: tuple[np.ndarray, np.ndarray, tuple[str, ...]] | None = None

    def model(self) -> AbstractParametric:
        """The template with the optimum put in."""
        return put(self.space.template, self.space.free, jnp.asarray(self.x))


def fit_stage(
    build: Callable[[AbstractParametric, tuple[str, ...]], AbstractObjective],
    space: ParameterSpace,
    settings: Settings,
    keys: tuple[jax.Array, jax.Array],
    *,
    search: Sequence[str] | None = None,
    n_landmarks: int,
    progress: bool = False,
    label: str = "DE",
    restart_landmarks: np.ndarray | None = None,
) -> StageFit:
    """Fit one stage: DE over ``search``, then LM over every free parameter.

    Args:
        build: the stage's data objective for a template and the names of its free
            parameters (the loss applied, no prior).
        space: the stage's parameters, box and prior.
        settings: DE, LM and restart settings.
        keys: the DE's key and the restarts' key.
        search: the free parameters DE searches (default: all); the others start at the
            template's values. An empty search skips DE.
        n_landmarks: landmarks behind each data block (the prior's weight is ``s/n``).
        progress: show DE's progress bar.
        label: the progress bar's label.
        restart_landmarks: the landmarks the restarts search on (default: all).
    """
    search = space.free if search is None else tuple(search)
    base = space.clip(space.theta())
    objective = with_prior(build(space.template, space.free), space, n_landmarks)
    data = build(space.template, space.free)
    lm_bounds = Bounds(space.lower, space.upper)
    t0 = time.perf_counter()
    de_info: dict[str, Any] = {"searched": list(search)}
    if space.d == 0:
        settings = replace(settings, polish=False)
    convergence: dict[str, list[float]] = {}
    population = None
    if search:
        sub = space if search == space.free else space.subspace(search, base)
        sub_objective = with_prior(build(sub.template, sub.free), sub, n_landmarks)
        de = minimise(sub_objective, settings.de(), Bounds(sub.lower, sub.upper),
                      key=keys[0], progress=progress, desc=label)  # fmt: skip
        x = space.embed(search, de.x, base)
        de_info.update(F=de.value, generations=de.steps, evaluations=de.evaluations,
                       converged=de.converged)  # fmt: skip
        convergence = {
            "best_F": [float(v) for v in de.best_history],
            "median_F": [float(v) for v in de.median_history],
            "median_generation": [int(g) for g in de.median_generations],
        }
        population = (de.population, de.fitness, search)
        found_by = "DE"
    else:
        sub = sub_objective = de = None
        x = base
        found_by = "the previous result"
    f = _value(objective, x)
    if de is not None:
        de_info["F"] = f  # the whole objective's value at DE's best (equal with a full search)
    t1 = time.perf_counter()
    polish: dict[str, Any] = {"ran": settings.polish, "accepted": False, "F_before": f}
    if settings.polish:
        lm = minimise(objective, POLISH, lm_bounds, x0=x)
        polish.update(steps=lm.steps, solver_converged=lm.converged)
        if np.isfinite(lm.value) and lm.value < f:
            x, f, found_by = lm.x, lm.value, f"{found_by} + LM"
        if settings.restarts > 0 and de is not None:
            x, f, found_by, polish["restarts"] = _restarts(
                objective, sub_objective, sub, space, de, base, keys[1], settings.restarts,
                (x, f, found_by), restart_landmarks,
            )  # fmt: skip
        polish.update(accepted=bool(f < polish["F_before"]), F_after=f)
    polish["found_by"] = found_by
    t2 = time.perf_counter()
    return StageFit(
        space=space, objective=objective, data=data, x=np.asarray(x, dtype=float), de=de_info,
        polish=polish, convergence=convergence, timings={"de": t1 - t0, "polish": t2 - t1},
        population=population,
    )  # fmt: skip


def _restarts(objective, sub_objective, sub, space, de, base, key, restarts, fit, landmarks):
    """LM (on ``sub``, the searched parameters) from the final population's other optima and
    from hypercube points, all at once; the end point with the lowest value of ``objective``,
    polished on all free parameters, replaces ``fit = (x, value, found_by)`` if lower."""
    x, f, found_by = fit
    lower, upper = sub.lower, sub.upper
    leaders = mode_leaders(de.population, de.fitness, lower, upper)[0][1:MAX_MODES]
    points = np.array(_lhs(key, restarts, lower, upper))
    k = min(len(leaders), restarts)
    points[:k] = leaders[:k]
    searched = sub_objective if landmarks is None else sub_objective.on_landmarks(landmarks)
    ends = minimise_starts(
        searched, LevenbergMarquardt(rtol=1e-10, atol=0.0, max_steps=RESTART_STEPS),
        Bounds(lower, upper), points,
    ).x  # fmt: skip
    full = np.array([space.embed(sub.free, e, base) for e in ends])
    values = np.array([_value(objective, e) for e in full])
    values = np.where(np.isfinite(values), values, np.inf)
    i = int(np.argmin(values))
    x_i, f_i = full[i], float(values[i])
    narrowed = searched is not sub_objective or sub is not space
    if (narrowed and f_i < f + 1e-4) or f_i < f - BETTER_BY_MM:
        # The batch stops on a looser rule than the polish (and may have searched fewer
        # landmarks or parameters): finish the winner as the DE's best was finished.
        lm = minimise(objective, POLISH, Bounds(space.lower, space.upper), x0=x_i)
        if np.isfinite(lm.value) and lm.value < f_i:
            x_i, f_i = lm.x, lm.value
    if f_i < f - BETTER_BY_MM:
        x, f = x_i, f_i
        found_by = (
            f"LM from another optimum of the final DE population (restart {i + 1} of {restarts})"
            if i < k
            else f"LM from a Latin-hypercube start (restart {i + 1} of {restarts})"
        )
    info = {
        "starts": restarts, "from_population": int(k), "best_F": f_i,
        # How many restarts ended within 1e-4 mm of the result: few say the basin was found
        # by few starts, so a larger budget might find a lower one.
        "reached_result": int(np.sum(values <= f + 1e-4)),
    }  # fmt: skip
    if landmarks is not None:
        info["landmarks"] = len(landmarks)
    return x, f, found_by, info


def _prior_report(stage: StageFit) -> dict[str, Any] | None:
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
                                             P_full)["precision"])  # fmt: skip
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
        out.append({
            "param": name, "mean": float(prior.mean[j]),
            "sigma": sp if math.isfinite(sp) else None, "value": float(stage.x[idx[j]]),
            "posterior_sigma": spost, "pull": float(pull), "marginal_pull": float(marginal),
        })  # fmt: skip
    report = {
        "source": prior.source,
        "names": list(prior.names),
        "mean": prior.mean.tolist(),
        "precision": prior.precision.tolist(),
        "data_scale_mm": prior.data_scale_mm,
        "pulls": out,
    }
    if prior.data_sigma_mm is not None:
        report["data_sigma_mm"] = prior.data_sigma_mm
    return report


@_xla.fast_compile
def _error_jacobian(objective, x):
    return error_jacobian(objective, x)


def _stage_result(stage: StageFit, prior_report: dict | None = None) -> StageResult:
    errors, (F, f1, f2), (n1, n2), value, terms = _report(stage.objective, stage.x)
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
) -> list[str]:
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
        return [
            f"{stage} has as many residuals ({residuals}: {n_landmarks} landmarks x "
            f"{RESIDUALS_PER_LANDMARK}{with_prior}) as free parameters: it can match the data "
            "exactly, so its F says nothing about its accuracy; touch more landmarks"
        ]
    return []


def bound_warnings(
    params: dict[str, float],
    cls: type[AbstractParametric],
    search: dict,
    free: Sequence[str] | None = None,
) -> list[str]:
    """One warning per free parameter sitting on a bound of its search range."""
    out = []
    for hit in bound_hits(params, cls, search):
        if free is not None and hit["param"] not in free:
            continue
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


def prior_warnings(stage: StageResult, label: str) -> list[str]:
    """One warning per prior parameter the data pull more than :data:`PULL_FLAG` σ away,
    largest pull first (the likeliest to have changed; correlated ones follow it)."""
    prior = getattr(stage, "prior", None)
    if not prior:
        return []
    out = []
    for p in sorted(prior["pulls"], key=lambda p: -abs(p["pull"])):
        if abs(p["pull"]) > PULL_FLAG:
            sigma = "" if p["sigma"] is None else f" ± {p['sigma']:.3g}"
            out.append(
                f"{label}: the data pull {p['param']} {abs(p['pull']):.1f} sigma from its prior "
                f"({prior['source']}: {p['mean']:.4g}{sigma}; fitted {p['value']:.4g}): the "
                f"prior may be wrong for this rig; refit {p['param']} (--refit) instead"
            )
    return out


def _sign_twin(stage: StageFit) -> dict[str, Any]:
    cls = type(stage.space.template)
    names = [n for n in getattr(cls, "sign_twin", ()) if n in stage.space.free]
    if len(names) != len(getattr(cls, "sign_twin", ())) or not names:
        return {}
    idx = [stage.space.free.index(n) for n in names]
    flipped = np.array(stage.x, copy=True)
    flipped[idx] = -flipped[idx]
    return {
        "params": list(names),
        "found": {n: float(stage.x[i]) for n, i in zip(names, idx, strict=True)},
        "F_found": _value(stage.data, stage.x),
        "F_flipped": _value(stage.data, flipped),
        "note": "flipping the signs of " + " and ".join(names) + " together mirrors the "
        "tablet through its own plane and gives the same F",
    }


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
    :func:`recalibrate` (no diagnostics: see :func:`handeye_jax.diagnose`)."""
    t_start = time.perf_counter()
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
    n = obs.n_landmarks
    # Refuse an undetermined fit before any work (the warnings come with the result).
    check_determined(n, plan.space1, "stage 1", dataset.source)
    check_determined(n, plan.space2, "stage 2", dataset.source)
    check_distinct(dataset.tablet_px, dataset.source)
    keys1, keys2 = _stage_keys(np.int64(settings.seed))
    with_loss = _loss_wrapper(settings, n)
    subset1 = subset2 = None
    if n > RESTART_LANDMARKS:
        subset1 = spread_landmarks(n, RESTART_LANDMARKS)
        subset2 = spread_landmarks(n, RESTART_LANDMARKS, include=obs.centre_index)

    def build1(template, free):
        return with_loss(Stage1Objective(template, obs, free))

    fit1 = fit_stage(build1, plan.space1, settings, keys1, search=plan.search1, n_landmarks=n,
                     progress=progress, label="stage 1 DE", restart_landmarks=subset1)  # fmt: skip
    stage1 = _stage_result(fit1, _prior_report(fit1))
    _check_finite(stage1, "stage 1", dataset.source)
    fit2, stage2, centres = fit_correction_stage(
        obs, fit1.model(), plan.space2, plan.search2, settings, keys2, progress, subset2,
        dataset.source,
    )  # fmt: skip
    warnings = _all_warnings(n, (plan.space1, plan.space2), stage1, stage2, dataset.search,
                             dataset.source)  # fmt: skip
    timings = {
        "stage1_de": fit1.timings["de"], "stage1_polish": fit1.timings["polish"],
        "stage2_de": fit2.timings["de"], "stage2_polish": fit2.timings["polish"],
        "total": time.perf_counter() - t_start,
    }  # fmt: skip
    recal = None
    if plan.previous is not None:
        recal = {"previous": plan.previous, "refit": list(plan.refit),
                 "others": "fixed" if plan.fixed else "prior"}  # fmt: skip
    return CalibrationResult(
        model=fit1.model(),
        correction=fit2.model(),
        rig=obs.rig,
        centres_mm=np.asarray(centres),
        centre_index=obs.centre_index,
        stage1=stage1,
        stage2=stage2,
        settings=settings,
        data=dataset,
        dataset_name=dataset.name,
        timings_s=timings,
        sign_twin=_sign_twin(fit1),
        warnings=warnings,
        recalibration=recal,
        fits=(fit1, fit2),
        heights=height_summary(fit1.model(), obs),
    )


def fit_correction_stage(
    obs: Observations,
    model: AbstractModel,
    space2: ParameterSpace,
    search2: Sequence[str],
    settings: Settings,
    keys2: tuple[jax.Array, jax.Array],
    progress: bool = False,
    subset: np.ndarray | None = None,
    source: str | Path | None = None,
) -> tuple[StageFit, StageResult, np.ndarray]:
    """Stage 2 on the chain points of a stage-1 ``model``: its fit, its result and its
    centres of rotation (rows: A1, A2), mm. ``source`` names the data in an error."""
    n = obs.n_landmarks
    points = _points(model, obs)
    with_loss = _loss_wrapper(settings, n)

    def build2(template, free):
        return with_loss(Stage2Objective(template, points, obs.centre_index, free))

    fit2 = fit_stage(build2, space2, settings, keys2, search=search2, n_landmarks=n,
                     progress=progress, label="stage 2 DE", restart_landmarks=subset)  # fmt: skip
    stage2 = _stage_result(fit2, _prior_report(fit2))
    _check_finite(stage2, "stage 2", source)
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
        result = replace(result, recalibration={**result.recalibration, "rig_changes": changes})
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
    n = dataset.n_landmarks
    subset = None
    if n > RESTART_LANDMARKS:
        centre = dataset.observations().centre_index
        subset = spread_landmarks(n, RESTART_LANDMARKS, include=centre)
    fit2, _, centres = fit_correction_stage(
        dataset.observations(), model, space2, space2.free, settings, keys2, False, subset,
        dataset.source,
    )  # fmt: skip
    return fit2.model(), centres


# -- the diagnostics, a step of their own --------------------------------------------------

#: How many times the diagnostics may replace a result's stage 1 with a lower refit (each
#: time stage 2 and the diagnostics are run again).
MAX_ADOPTIONS = 2


def _prior_of(report: dict[str, Any] | None) -> Prior | None:
    if not report:
        return None
    return Prior(tuple(report["names"]), report["mean"], report["precision"], report["source"],
                 report["data_scale_mm"], report.get("data_sigma_mm"))  # fmt: skip


def _spaces_of(result: CalibrationResult, search: dict) -> tuple[ParameterSpace, ParameterSpace]:
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
    return spaces[0], spaces[1]


def _all_warnings(n, spaces, stage1, stage2, search, path, convention_warning=None) -> list[str]:
    model_cls = type(spaces[0].template)
    warnings = fit_warnings(stage1, stage2)
    warnings += check_determined(n, spaces[0], "stage 1", path)
    warnings += check_determined(n, spaces[1], "stage 2", path)
    warnings += bound_warnings(stage1.params, model_cls, search, spaces[0].free)
    warnings += bound_warnings(stage2.params, AffinePair, search, spaces[1].free)
    warnings += prior_warnings(stage1, "stage 1") + prior_warnings(stage2, "stage 2")
    if convention_warning:
        warnings.append(convention_warning)
    return warnings


def _better_refit(objective, diagnostics: dict, space: ParameterSpace, f: float,
                  searched_fewer: bool):  # fmt: skip
    """The diagnostics' multi-start refit (declared convention) with the lowest value of
    ``objective``, if lower than ``f`` by more than :data:`BETTER_BY_MM`, as ``(x, value,
    elsewhere)`` (``elsewhere``: another optimum, not the fit's own refined); else None.

    ``searched_fewer``: the refits searched on fewer landmarks than ``objective`` has, so
    their end points are polished on all before they are compared.
    """
    found = []
    for mode in diagnostics["stage1"].get("local_optima", []):
        x_r = np.array([mode["params"][n] for n in space.free])
        found.append((_value(objective, x_r), x_r, bool(mode["differs_from_fit"])))
    found = sorted((c for c in found if np.isfinite(c[0])), key=lambda c: c[0])
    elsewhere = [c for c in found if c[2]]
    if searched_fewer and elsewhere:
        f_r, x_r, _ = elsewhere[0]
        lm = minimise(objective, POLISH, Bounds(space.lower, space.upper), x0=x_r)
        better = np.isfinite(lm.value) and lm.value < f_r
        found.append((lm.value, lm.x, True) if better else elsewhere[0])
        found.sort(key=lambda c: c[0])
    if found and found[0][0] < f - BETTER_BY_MM:
        return found[0][1], found[0][0], found[0][2]
    return None


@in_float64
def diagnose(
    result: CalibrationResult, *, search: dict | None = None, progress: bool = False
) -> CalibrationResult:
    """The result with its ``diagnostics``: uncertainty and identifiability, the optima in
    the final DE population, bound hits, leave-one-out, outliers and the convention check.

    All on each stage's free parameters (their priors included). A multi-start refit of stage
    1 that reaches a lower value than the fit becomes the result (stage 2 and the diagnostics
    are then run again on it), and stage 1's ``polish.found_by`` says so: a calibration never
    reports a worse optimum than it found.

    Args:
        result: a result just computed, or read from a file (the DE populations are then
            unknown, and the optima in them are not reported).
        search: the dataset's ``[search]`` overrides (a result read from a file does not
            record them; default: none).
        progress: show progress bars (of a stage-2 refit) on stderr.
    """
    from ._diagnostics import diagnostics_of

    t0 = time.perf_counter()
    settings = result.settings
    search = search or {}
    if result.data is None:
        raise InputError(None, "data", "the result does not carry its data: it cannot be "
                         "diagnosed; calibrate again")  # fmt: skip
    obs = result.data.observations()
    n = obs.n_landmarks
    if result.fits is not None:
        fit1, fit2 = result.fits
        spaces = (fit1.space, fit2.space)
        x1, x2 = fit1.x, fit2.x
        populations = (fit1.population, fit2.population)
    else:
        spaces = _spaces_of(result, search)
        x1 = np.array([result.stage1.params[nm] for nm in spaces[0].free])
        x2 = np.array([result.stage2.params[nm] for nm in spaces[1].free])
        populations = (None, None)
    loss = get_loss(settings.loss, settings.loss_scale_mm)
    with_loss = _loss_wrapper(settings, n)
    stage1, stage2, pol1 = result.stage1, result.stage2, dict(result.stage1.polish)
    centres, t_restage = result.centres_mm, 0.0
    _, keys2 = _stage_keys(np.int64(settings.seed))
    fits = result.fits
    gaussian = isinstance(loss, L1Loss)  # as the fit's objectives (with_prior)
    for adoption in range(MAX_ADOPTIONS + 1):
        s1 = with_prior(Stage1Objective(spaces[0].template, obs, spaces[0].free), spaces[0], n,
                        gaussian=gaussian)  # fmt: skip
        points = _points(put(spaces[0].template, spaces[0].free, jnp.asarray(x1)), obs)
        s2 = Stage2Objective(spaces[1].template, points, obs.centre_index, spaces[1].free)
        s2 = with_prior(s2, spaces[1], n, gaussian=gaussian)
        diagnostics = diagnostics_of(
            stage1=s1, stage2=s2, spaces=spaces, loss=loss, loss_scale_mm=settings.loss_scale_mm,
            x=(x1, x2), stage_results=(stage1, stage2), populations=populations, search=search,
            seed=settings.seed, depth_mm=np.asarray(obs.depth_mm),
            declared=(float(obs.rig.angle_zero_deg), int(obs.rig.angle_sign)),
        )  # fmt: skip
        obj1 = with_loss(s1)
        better = _better_refit(obj1, diagnostics, spaces[0], _value(obj1, x1), n > REFIT_LANDMARKS)
        if better is None or adoption == MAX_ADOPTIONS or spaces[0].d == 0:
            break
        # A refit reached a lower value than the fit (another optimum, or the fit's own one
        # further down): take it, refit stage 2 on its points, and diagnose again from it.
        t_a = time.perf_counter()
        x_r, f_r, elsewhere = better
        lm = minimise(obj1, POLISH, Bounds(spaces[0].lower, spaces[0].upper), x0=x_r)
        if np.isfinite(lm.value) and lm.value < f_r:
            x_r, f_r = lm.x, lm.value
        pol1 = {
            **pol1, "accepted": bool(f_r < result.stage1.de.get("F", np.inf)), "F_after": f_r,
            "found_by": "diagnostics multi-start refit" if elsewhere else
            f"{pol1['found_by'].split(', refined')[0]}, refined by the diagnostics' refit "
            "from it",
            "replaced_F": [*pol1.get("replaced_F", []), _value(obj1, x1)],
        }  # fmt: skip
        x1 = np.asarray(x_r, dtype=float)
        new1 = StageFit(spaces[0], obj1, with_loss(Stage1Objective(spaces[0].template, obs,
                        spaces[0].free)), x1, result.stage1.de, pol1, result.stage1.convergence,
                        {}, populations[0])  # fmt: skip
        stage1 = _stage_result(new1, _prior_report(new1))
        _check_finite(stage1, "stage 1", None)
        search2 = spaces[1].free if spaces[1].prior is None else ()
        fit2, stage2, centres = fit_correction_stage(
            obs, new1.model(), spaces[1], search2, settings, keys2, progress
        )
        x2 = fit2.x
        populations = (populations[0], fit2.population)
        fits = (new1, fit2)
        centres = np.asarray(centres).tolist()
        t_restage += time.perf_counter() - t_a
    timings = dict(result.timings_s)
    timings["diagnostics"] = time.perf_counter() - t0 - t_restage
    if t_restage:
        timings["refit_adoption"] = t_restage
    warnings = _all_warnings(n, spaces, stage1, stage2, search, None,
                             diagnostics["convention"]["warning"])  # fmt: skip
    sign_twin = result.sign_twin
    if fits is not None and fits is not result.fits:
        sign_twin = _sign_twin(fits[0])
    if fits is not result.fits:  # a refit was adopted: the models are the new fits'
        result = replace(result, model=fits[0].model(), correction=fits[1].model(),
                         heights=height_summary(fits[0].model(), obs))  # fmt: skip
    result = replace(
        result, stage1=stage1, stage2=stage2, centres_mm=centres, diagnostics=diagnostics,
        warnings=warnings, timings_s=timings, sign_twin=sign_twin, fits=fits,
    )  # fmt: skip
    diagnostics["scope"] = capture_scope(result)  # where the calibration holds (_scope)
    return result
