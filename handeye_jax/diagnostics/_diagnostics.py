"""What a calibration can and cannot tell: the ``diagnostics`` object of a result.

For each stage: parameter standard deviations and weak directions (:mod:`.identifiability`),
the distinct optima left in the final DE population, parameters on a search-range bound,
leave-one-out held-out errors (:mod:`.refits`) and outlier landmarks; for stage 1 also the
hand-angle convention check. Everything is plain JSON-ready data; :mod:`.summary` prints it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .._core import Stages
from ..calibration import (
    CONVENTIONS,
    REFIT_STARTS,
    FittedStage,
    Settings,
    StageResult,
    bound_hits,
)
from ..data import Observations
from ..optim import MAX_MODES, mode_leaders
from ..problem import ParameterSpace, analyse_jacobian, get_loss
from ._refits import refits

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
#: Most LM iterations of each refit (the random starts per convention: REFIT_STARTS, the
#: fit's own multi-start refits).
REFIT_STEPS = 400


def population_modes(
    population: np.ndarray,
    fitness: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    names: Sequence[str],
    sign_twin: Sequence[str] = (),
    flat_steps: Sequence[dict[str, float]] = (),
    reference: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """The distinct optima in a final population, best first (at most :data:`MAX_MODES`).

    Members are grouped as :func:`mode_leaders` does. Groups whose best F is within
    :data:`MODE_F_MARGIN_MM` of the overall best are reported, each with its best member's
    parameters and the parameters in which it differs from ``reference``.

    Args:
        population, fitness: the final population ``(N, d)`` and its F (mm).
        lower, upper: the search box.
        names: parameter names.
        sign_twin: parameters whose joint sign flip is a known symmetry (named when found).
        flat_steps: directions along which the data barely or never change F (``{name:
            step}``, the weak directions of
            :func:`~handeye_jax._identifiability.analyse_jacobian`); members that differ only
            along them lie in one valley and are one optimum (e.g. the DH model's θc1 − γc,
            or the camera's xc–βc trade-off).
        reference: the reported fit, to which each optimum is compared (by default the
            population's best member).
    """
    lead, f, counts = mode_leaders(population, fitness, lower, upper, names, flat_steps)
    width = np.asarray(upper) - np.asarray(lower)
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
        modes.append({"F": float(f_lead), "members": int(count), "differs_from_fit": differ,
                      "sign_twin": twin,
                      "params": dict(zip(names, (float(v) for v in x), strict=True))})  # fmt: skip
    return modes[:MAX_MODES]


def outliers(residuals_mm: list[dict[str, Any]], threshold_mm: float) -> list[int]:
    """Landmarks with an error length (either term) above ``threshold_mm``."""
    return [
        int(r["m"])
        for r in residuals_mm
        if max(r["image_vs_tablet_mm"], r["hand_mm"]) > threshold_mm
    ]


def _loo(image_vs_tablet: np.ndarray, hand: np.ndarray, in_sample_F: float) -> dict[str, Any]:
    f1, f2 = float(np.mean(image_vs_tablet)), float(np.mean(hand))
    return {
        "held_out_mm": [
            {"m": m, "image_vs_tablet_mm": float(a), "hand_mm": float(b)}
            for m, (a, b) in enumerate(zip(image_vs_tablet, hand, strict=True))
        ],
        "f1": f1, "f2": f2, "F": f1 + f2, "in_sample_F": in_sample_F,
    }  # fmt: skip


def convention_check(
    F: np.ndarray, declared: tuple[float, int], F_fit: float, landmarks: int = 0
) -> dict[str, Any]:
    """Compare F1st under the 8 conventions with the declared one; a warning if beaten.

    ``landmarks``: how many landmarks the refits searched on, if fewer than all (0: all).
    """
    fits = [
        {"zero_deg": z, "sign": s, "F": float(f)} for (z, s), f in zip(CONVENTIONS, F, strict=True)
    ]
    key = (float(declared[0]) % 360.0, int(declared[1]))
    if key in CONVENTIONS:
        i_decl = CONVENTIONS.index(key)
        F_decl = min(float(F[i_decl]), F_fit)
        fits[i_decl]["F"] = F_decl
    else:  # a declared zero off the 90-degree grid: compare with the fit itself
        fits.append({"zero_deg": float(declared[0]), "sign": int(declared[1]), "F": F_fit})
        i_decl, F_decl = len(fits) - 1, F_fit
    i_best = int(np.argmin([c["F"] for c in fits]))
    best = fits[i_best]
    margin = max(CONVENTION_MARGIN_MM, CONVENTION_FRACTION * F_decl)
    warning = None
    if i_best != i_decl and best["F"] < F_decl - margin:
        warning = (
            f"hand-angle convention zero = {best['zero_deg']:g} deg, sign = {best['sign']:+d} "
            f"fits markedly better (F1st = {best['F']:.4f} mm) than the dataset's zero = "
            f"{declared[0]:g} deg, sign = {declared[1]:+d} (F1st = {F_decl:.4f} mm): check "
            "[hand_angle] in the dataset"
        )
    return {
        "declared": {"zero_deg": float(declared[0]), "sign": int(declared[1])},
        "fits": fits,
        "passed": warning is None,
        "warning": warning,
        "method": f"LM from {REFIT_STARTS} uniform starts per convention "
        f"(at most {REFIT_STEPS} iterations each), the declared one also from the fit; the pen's "
        "search box is kept"
        + (
            f"; the refits searched on {landmarks} landmarks spread over the touch order, and "
            "F1st is that of all landmarks at their end points"
            if landmarks
            else ""
        ),
    }


def _prior_precision(space: ParameterSpace) -> np.ndarray | None:
    """The prior's precision in the space's free coordinates (zeros elsewhere), or None."""
    if space.prior is None:
        return None
    P = np.zeros((space.d, space.d))
    idx = space.prior_indices()
    P[np.ix_(idx, idx)] = space.prior.precision
    return P


def diagnostics_of(
    stages: Stages[FittedStage],
    results: Stages[StageResult],
    settings: Settings,
    obs: Observations,
    search: dict,
) -> dict[str, Any]:
    """The ``diagnostics`` object of a result, on each stage's free parameters.

    Args:
        stages: each stage as fitted (:func:`~handeye_jax.calibration.fitted_stages`).
        results: each stage's numbers (:class:`~handeye_jax.StageResult`).
        settings: the calibration's settings: its loss and the seed the convention
            multi-starts draw from.
        obs: the observations fitted (depths explain a shift–tilt trade-off; the rig's
            convention is the declared one).
        search: the dataset's ``[search]`` overrides.
    """
    loss = get_loss(settings.loss, settings.loss_scale_mm)
    out = refits(stages, loss, settings.seed, REFIT_STARTS, REFIT_STEPS)
    loo = Stages(_loo(out.loo1_image_vs_tablet, out.loo1_hand, results.stage1.F),
                 _loo(out.loo2_image_vs_tablet, out.loo2_hand, results.stage2.F))  # fmt: skip
    jacobians = Stages((out.errors1, out.jacobian1), (out.errors2, out.jacobian2))
    depth = np.asarray(obs.depth_mm)
    threshold = OUTLIER_FACTOR * settings.loss_scale_mm
    found = {}
    for key, stage in stages.items():
        result = getattr(results, key)
        found[key] = _stage_diagnostics(stage, getattr(jacobians, key), depth, result, search)
        found[key].update(loo=getattr(loo, key), loo_method=out.loo_method,
                          outliers=outliers(result.residuals_mm, threshold))  # fmt: skip
    space1 = stages.stage1.space
    found["stage1"]["local_optima"] = population_modes(
        out.declared_params, out.declared_F, space1.lower, space1.upper, space1.free,
        tuple(n for n in type(space1.template).sign_twin if n in space1.free),
        [w["step"] for w in found["stage1"]["weak_directions"]], np.asarray(stages.stage1.x),
    )  # fmt: skip
    n = obs.n_landmarks
    searched = out.refit_landmarks if out.refit_landmarks < n else 0
    declared = (float(obs.rig.angle_zero_deg), int(obs.rig.angle_sign))
    return {
        "loss": {"name": loss.name, "scale_mm": float(settings.loss_scale_mm)},
        "outlier_threshold_mm": threshold,
        **found,
        "convention": convention_check(out.convention_F, declared, results.stage1.F, searched),
    }


def _stage_diagnostics(stage: FittedStage, jacobian: tuple[np.ndarray, np.ndarray],
                       depth_mm: np.ndarray, result: StageResult,
                       search: dict) -> dict[str, Any]:  # fmt: skip
    """One stage's uncertainty, weak directions (from its error vectors and their Jacobian at
    the fit), the optima in its final DE population and its parameters on a bound."""
    space = stage.space
    cls = type(space.template)
    e, J = jacobian
    units = [cls.param_units[cls.param_names.index(n)] for n in space.free]
    jac = analyse_jacobian(e, J, space.free, units, depth_mm, _prior_precision(space))
    flat = [w["step"] for w in jac["weak_directions"]]
    modes = []
    pop = stage.population
    if pop is not None and pop.searched:
        idx = [space.free.index(n) for n in pop.searched]
        twin = tuple(n for n in cls.sign_twin if n in pop.searched)
        steps = [{n: v for n, v in st.items() if n in pop.searched} for st in flat]
        modes = population_modes(
            pop.members, pop.values, space.lower[idx], space.upper[idx], pop.searched, twin,
            [st for st in steps if st], np.asarray(stage.x)[idx],
        )  # fmt: skip
    hits = [h for h in bound_hits(result.params, cls, search) if h["param"] in space.free]
    return {**jac, "free": list(space.free), "modes": modes, "bound_hits": hits}
