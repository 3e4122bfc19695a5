"""What a calibration can and cannot tell: a result's :class:`~handeye_jax.calibration.Diagnostics`.

For each stage: parameter standard deviations and weak directions (the Jacobian's analysis),
the distinct optima left in the final DE population, parameters on a search-range bound,
leave-one-out held-out errors (:mod:`._refits`) and outlier landmarks; for stage 1 also the
optima of the multi-start refits and the hand-angle convention check. The report prints it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._core import Stages
from ..calibration import (
    CONVENTIONS,
    REFIT_STARTS,
    AdviceContext,
    Convention,
    ConventionCheck,
    ConventionFit,
    Diagnostics,
    FittedStage,
    HeldOut,
    LeaveOneOut,
    LossInfo,
    Mode,
    Population,
    Residual,
    SearchReport,
    Settings,
    StageDiagnostics,
    StageResult,
    bound_hits,
    prior_information,
)
from ..data import Observations
from ..optim import MAX_MODES, Box, mode_leaders
from ..problem import ParameterSpace, analyse_jacobian, closed_form_estimate, get_loss
from ._refits import RefitBudget, refits

#: A distinct optimum is reported when its best F is within this many mm of the best.
MODE_F_MARGIN_MM = 0.5
#: Parameters that differ by more than this fraction of their range are listed per optimum.
MODE_PARAM_FRACTION = 0.01
#: A landmark is an outlier when an error length exceeds this many loss scales.
OUTLIER_FACTOR = 3.0
#: Another convention "fits markedly better" when its F1st is lower by at least this
#: fraction of the declared one's, and at least CONVENTION_MARGIN_MM.
CONVENTION_FRACTION = 0.1
CONVENTION_MARGIN_MM = 0.05
#: Conventions of one sign whose F1st are this close, mm, tie (their zero is not told apart).
ZERO_TIE_MM = 1e-6
#: Most LM iterations of each refit (the random starts per convention: REFIT_STARTS, the
#: fit's own multi-start refits).
REFIT_STEPS = 400


def population_modes(
    population: Population,
    box: Box,
    *,
    sign_twin: Sequence[str] = (),
    flat_steps: Sequence[dict[str, float]] = (),
    reference: np.ndarray | None = None,
) -> tuple[Mode, ...]:
    """The distinct optima in a final population, best first (at most :data:`MAX_MODES`).

    Members are grouped as :func:`mode_leaders` does. Groups whose best F is within
    :data:`MODE_F_MARGIN_MM` of the overall best are reported, each with its best member's
    parameters and the parameters in which it differs from ``reference``.

    Args:
        population: the members ``(N, d)``, their F (mm) and the parameters' names.
        box: the search box.
        sign_twin: parameters whose joint sign flip is a known symmetry (named when found).
        flat_steps: directions along which the data barely or never change F (``{name:
            step}``, the weak directions of
            :func:`~handeye_jax.analyse_jacobian`); members that differ only
            along them lie in one valley and are one optimum (e.g. the DH model's θc1 − γc,
            or the camera's xc–βc trade-off).
        reference: the reported fit, to which each optimum is compared (by default the
            population's best member).
    """
    names = population.searched
    lead, f, counts = mode_leaders(population.members, population.values, box.lower, box.upper,
                                   names, flat_steps)  # fmt: skip
    width = box.upper - box.lower
    best = lead[0] if reference is None else np.asarray(reference, dtype=float)
    twin_idx = [list(names).index(n) for n in sign_twin]
    modes = []
    for x, f_lead, count in zip(lead, f, counts, strict=True):
        if f_lead > f[0] + MODE_F_MARGIN_MM:
            continue
        delta = x - best
        differ = {
            n: float(delta[k])
            for k, n in enumerate(names)
            if abs(delta[k]) > MODE_PARAM_FRACTION * width[k]
        }
        twin = (
            bool(twin_idx)
            and all(abs(x[k] + best[k]) <= MODE_PARAM_FRACTION * width[k] for k in twin_idx)
            and any(abs(delta[k]) > MODE_PARAM_FRACTION * width[k] for k in twin_idx)
        )
        params = dict(zip(names, (float(v) for v in x), strict=True))
        modes.append(Mode(F_mm=float(f_lead), members=int(count), differs_from_fit=differ,
                          sign_twin=twin, params=params))  # fmt: skip
    return tuple(modes[:MAX_MODES])


def outliers(residuals_mm: Sequence[Residual], threshold_mm: float) -> tuple[int, ...]:
    """Landmarks with an error length (either term) above ``threshold_mm``."""
    return tuple(int(r.m) for r in residuals_mm
                 if max(r.image_vs_tablet_mm, r.hand_mm) > threshold_mm)  # fmt: skip


def _loo(image_vs_tablet: np.ndarray, hand: np.ndarray, in_sample_F: float) -> LeaveOneOut:
    f1, f2 = float(np.mean(image_vs_tablet)), float(np.mean(hand))
    held = tuple(HeldOut(m, float(a), float(b))
                 for m, (a, b) in enumerate(zip(image_vs_tablet, hand, strict=True)))  # fmt: skip
    return LeaveOneOut(held, f1, f2, f1 + f2, in_sample_F)


def convention_check(
    F: np.ndarray, declared: tuple[float, int], F_fit: float, landmarks: int = 0
) -> ConventionCheck:
    """Compare F1st under the 8 conventions with the declared one; a warning if beaten.

    ``landmarks``: how many landmarks the refits searched on, if fewer than all (0: all).
    """
    fits = [ConventionFit(z, s, float(f)) for (z, s), f in zip(CONVENTIONS, F, strict=True)]
    key = (float(declared[0]) % 360.0, int(declared[1]))
    if key in CONVENTIONS:
        i_decl = CONVENTIONS.index(key)
        F_decl = min(float(F[i_decl]), F_fit)
        fits[i_decl] = replace(fits[i_decl], F_mm=F_decl)
    else:  # a declared zero off the 90-degree grid: compare with the fit itself
        fits.append(ConventionFit(float(declared[0]), int(declared[1]), F_fit))
        i_decl, F_decl = len(fits) - 1, F_fit
    i_best = int(np.argmin([c.F_mm for c in fits]))
    best = fits[i_best]
    # The zero only turns the hand frame, which the pen offset and the camera mount absorb:
    # zeros of one sign tie unless the search box tells them apart. Keep the declared zero.
    ties = [c for c in fits if c.sign == best.sign and c.zero_deg == float(declared[0]) % 360.0
            and c.F_mm <= best.F_mm + ZERO_TIE_MM]  # fmt: skip
    tied_zero = bool(ties) and sum(c.sign == best.sign and c.F_mm <= best.F_mm + ZERO_TIE_MM
                                   for c in fits) > 1  # fmt: skip
    if ties:
        best, i_best = ties[0], fits.index(ties[0])
    margin = max(CONVENTION_MARGIN_MM, CONVENTION_FRACTION * F_decl)
    warning = None
    if i_best != i_decl and best.F_mm < F_decl - margin:
        zero_note = (" (its other zeros fit alike: the pen offset and the camera mount absorb "
                     "the zero, so keep yours)" if tied_zero else "")  # fmt: skip
        warning = (
            f"hand-angle convention zero = {best.zero_deg:g} deg, sign = {best.sign:+d} "
            f"fits markedly better (F1st = {best.F_mm:.4f} mm){zero_note} than the dataset's "
            f"zero = {declared[0]:g} deg, sign = {declared[1]:+d} (F1st = {F_decl:.4f} mm): "
            "check [hand_angle] in the dataset"
        )
    return ConventionCheck(
        declared=Convention(float(declared[0]), int(declared[1])),
        fits=tuple(fits),
        passed=warning is None,
        warning=warning,
        method=f"LM from {REFIT_STARTS} uniform starts per convention "
        f"(at most {REFIT_STEPS} iterations each), the declared one also from the fit; the pen's "
        "search box is kept"
        + (
            f"; the refits searched on {landmarks} landmarks spread over the touch order, and "
            "F1st is that of all landmarks at their end points"
            if landmarks
            else ""
        ),
    )


def convention_estimates(space: ParameterSpace, obs: Observations) -> np.ndarray | None:
    """The closed-form estimate under each of :data:`CONVENTIONS`, in ``space``'s free
    parameters, ``(8, d)`` (NaN where the data or the model give none), for a fit of every
    parameter without a prior; else ``None``.

    A box around the declared convention's estimate need not hold another convention's
    optimum (its pen and camera turned): each convention's refits also start from its own
    estimate."""
    cls = type(space.template)
    if space.prior is not None or space.free != cls.param_names:
        return None
    out = np.full((len(CONVENTIONS), space.d), np.nan)
    for i, (zero, sign) in enumerate(CONVENTIONS):
        other = eqx.tree_at(lambda o: (o.rig.angle_zero_deg, o.rig.angle_sign), obs,
                            (jnp.asarray(zero, dtype=float), jnp.asarray(float(sign))))  # fmt: skip
        try:
            params = closed_form_estimate(other).candidates[0].params(cls)
        except (ValueError, NotImplementedError):
            continue
        out[i] = [params[n] for n in space.free]
    return out


def diagnostics_of(
    stages: Stages[FittedStage],
    results: Stages[StageResult],
    settings: Settings,
    obs: Observations,
    report: SearchReport | None = None,
) -> Diagnostics:
    """The diagnostics of a result, on each stage's free parameters (the scope aside:
    :func:`~handeye_jax.capture_scope` reads these).

    Args:
        stages: each stage as fitted (:func:`~handeye_jax.calibration.fitted_stages`).
        results: each stage's numbers (:class:`~handeye_jax.StageResult`).
        settings: the calibration's settings: its loss and the seed the convention
            multi-starts draw from.
        obs: the observations fitted (depths explain a shift–tilt trade-off; the rig's
            convention is the declared one).
        report: where the result searched (for the advice on a parameter at a bound).
    """
    loss = get_loss(settings.loss, settings.loss_scale_mm)
    extra = None
    if report is not None and report.preset == "estimate":
        extra = convention_estimates(stages.stage1.space, obs)
    budget = RefitBudget(settings.seed, REFIT_STARTS, REFIT_STEPS)
    out = refits(stages, loss, budget, convention_starts=extra)
    loo = Stages(_loo(out.loo1_image_vs_tablet, out.loo1_hand, results.stage1.F),
                 _loo(out.loo2_image_vs_tablet, out.loo2_hand, results.stage2.F))  # fmt: skip
    jacobians = Stages((out.errors1, out.jacobian1), (out.errors2, out.jacobian2))
    depth = np.asarray(obs.depth_mm)
    threshold = OUTLIER_FACTOR * settings.loss_scale_mm
    found = {}
    for key, stage in stages.items():
        result = getattr(results, key)
        found[key] = replace(
            _stage_diagnostics(stage, getattr(jacobians, key), depth, result, key,
                               AdviceContext(report, obs)),
            loo=getattr(loo, key), loo_method=out.loo_method,
            outliers=outliers(result.residuals_mm, threshold),
        )  # fmt: skip
    space1 = stages.stage1.space
    local = population_modes(
        Population(out.declared_params, out.declared_F, space1.free), space1.box,
        sign_twin=tuple(n for n in type(space1.template).sign_twin if n in space1.free),
        flat_steps=[w.step for w in found["stage1"].weak_directions],
        reference=np.asarray(stages.stage1.x),
    )  # fmt: skip
    n = obs.n_landmarks
    searched = out.refit_landmarks if out.refit_landmarks < n else 0
    declared = (float(obs.rig.angle_zero_deg), int(obs.rig.angle_sign))
    return Diagnostics(
        loss=LossInfo(settings.loss, float(settings.loss_scale_mm)),
        outlier_threshold_mm=threshold,
        stage1=replace(found["stage1"], local_optima=local),
        stage2=found["stage2"],
        convention=convention_check(out.convention_F, declared, results.stage1.F, searched),
    )


def _stage_diagnostics(stage: FittedStage, jacobian: tuple[np.ndarray, np.ndarray],
                       depth_mm: np.ndarray, result: StageResult, key: str,
                       context: AdviceContext) -> StageDiagnostics:  # fmt: skip
    """One stage's uncertainty, weak directions (from its error vectors and their Jacobian at
    the fit), the optima in its final DE population and its parameters on a bound (with what
    would help, from ``context``)."""
    space = stage.space
    cls = type(space.template)
    e, J = jacobian
    units = [cls.param_units[cls.param_names.index(n)] for n in space.free]
    jac = analyse_jacobian(e, J, space.free, units, depth_mm, prior_information(space))
    flat = [w.step for w in jac.weak_directions]
    modes: tuple[Mode, ...] = ()
    pop = stage.population
    if pop is not None and pop.searched:
        idx = [space.free.index(n) for n in pop.searched]
        steps = [{n: v for n, v in st.items() if n in pop.searched} for st in flat]
        modes = population_modes(
            pop, Box(space.lower[idx], space.upper[idx]),
            sign_twin=tuple(n for n in cls.sign_twin if n in pop.searched),
            flat_steps=[st for st in steps if st], reference=np.asarray(stage.x)[idx],
        )  # fmt: skip
    context = replace(context, analysis=lambda _: jac)
    hits = bound_hits(result, space, key, context)
    return StageDiagnostics(**vars(jac), free=tuple(space.free), modes=modes, bound_hits=hits)
