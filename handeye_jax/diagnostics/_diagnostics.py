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

from ..models import AbstractParametric
from ..optim import Bounds
from ..problem import AbstractLoss, AbstractObjective, ParameterSpace, analyse_jacobian
from ._refits import CONVENTIONS, refits

# A parameter closer than this fraction of its range to a bound is reported as on the bound.
BOUND_FRACTION = 1e-3
#: Population members closer than this to a better member, in every parameter (as a fraction
#: of its search range), belong to its optimum.
MODE_RADIUS = 0.05
#: At most this many optima are reported, best first.
MAX_MODES = 5
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
#: Budget of the refits: random LM starts per convention, most LM iterations per refit.
CONVENTION_STARTS = 6
REFIT_STEPS = 400


def bound_hits(
    params: dict[str, float], cls: type[AbstractParametric], search: dict
) -> list[dict[str, Any]]:
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
            out.append({
                "param": name, "value": float(v), "unit": unit, "side": side,
                "range": [float(lo), float(hi)], "widen_to": [float(wider[0]), float(wider[1])],
            })  # fmt: skip
    return out


def mode_leaders(
    population: np.ndarray,
    fitness: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    names: Sequence[str] = (),
    flat_steps: Sequence[dict[str, float]] = (),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The best member of each distinct optimum in a population, best first.

    Members are grouped greedily in order of fitness: a member within :data:`MODE_RADIUS` of
    a group's best member in every parameter (as a fraction of its range) joins that group.
    Non-finite fitnesses are left out.

    Args:
        population, fitness: the population ``(N, d)`` and its F (mm).
        lower, upper: the search box.
        names, flat_steps: parameter names, and directions along which F barely or never
            changes (``{name: step}``); members apart only along them are one optimum (see
            :func:`population_modes`).

    Returns:
        ``(x, F, members)``: each optimum's best member ``(k, d)``, its F ``(k,)`` and how
        many members the group holds ``(k,)``.
    """
    ok = np.isfinite(fitness)
    pop, f = np.asarray(population)[ok], np.asarray(fitness)[ok]
    order = np.argsort(f, kind="stable")
    pop, f = pop[order], f[order]
    width = np.asarray(upper) - np.asarray(lower)
    u = (pop - lower) / width
    if flat_steps:
        V = np.array([[st.get(n, 0.0) for n in names] for st in flat_steps]) / width
        Q, _ = np.linalg.qr(V.T)  # orthonormal basis of the flat directions
        u = u - (u @ Q) @ Q.T
    leaders: list[int] = []
    counts: list[int] = []
    for i in range(len(f)):
        if leaders:
            dist = np.abs(u[leaders] - u[i]).max(axis=1)
            j = int(np.argmin(dist))
            if dist[j] < MODE_RADIUS:
                counts[j] += 1
                continue
        leaders.append(i)
        counts.append(1)
    return pop[leaders], f[leaders], np.array(counts, dtype=int)


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
        "method": f"LM from {CONVENTION_STARTS} uniform starts per convention "
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
    *,
    stage1: AbstractObjective,
    stage2: AbstractObjective,
    spaces: tuple[ParameterSpace, ParameterSpace],
    loss: AbstractLoss,
    loss_scale_mm: float,
    x: tuple[np.ndarray, np.ndarray],
    stage_results: tuple[Any, Any],
    populations: tuple[Any, Any],
    search: dict,
    seed: int,
    depth_mm: np.ndarray,
    declared: tuple[float, int],
) -> dict[str, Any]:
    """The ``diagnostics`` object of a result, on each stage's free parameters.

    Args:
        stage1, stage2: the stages' objectives as fitted (prior included, loss not).
        spaces: the stages' parameter spaces.
        loss, loss_scale_mm: the loss the fit used, and its scale in mm.
        x: each stage's optimum (free parameters).
        stage_results: each stage's :class:`~handeye_jax.result.StageResult`.
        populations: each stage's final DE ``(population, fitness, names searched)``, or
            ``None`` where it is not known (a result read from a file).
        search: the dataset's ``[search]`` overrides.
        seed: the calibration's seed (the convention multi-starts draw from it).
        depth_mm: the landmarks' depths, mm (to explain a shift–tilt trade-off).
        declared: the dataset's hand-angle convention ``(zero deg, sign)``.
    """
    bounds = [Bounds(sp.lower, sp.upper) for sp in spaces]
    out = refits(
        stage1, stage2, loss, np.asarray(x[0]), np.asarray(x[1]), bounds[0], bounds[1], seed,
        CONVENTION_STARTS, REFIT_STEPS,
    )  # fmt: skip
    loo = (
        _loo(out.loo1_image_vs_tablet, out.loo1_hand, stage_results[0].F),
        _loo(out.loo2_image_vs_tablet, out.loo2_hand, stage_results[1].F),
    )
    threshold = OUTLIER_FACTOR * loss_scale_mm
    stages = {}
    jacobians = ((out.errors1, out.jacobian1), (out.errors2, out.jacobian2))
    flat: dict[int, list[dict[str, float]]] = {}
    for k, (space, (e, J), sr, pop) in enumerate(
        zip(spaces, jacobians, stage_results, populations, strict=True)
    ):
        cls = type(space.template)
        units = [cls.param_units[cls.param_names.index(n)] for n in space.free]
        jac = analyse_jacobian(e, J, space.free, units, depth_mm, _prior_precision(space))
        flat[k] = [w["step"] for w in jac["weak_directions"]]
        modes = []
        if pop is not None and pop[2]:
            members, fitness_, names = pop
            idx = [space.free.index(n) for n in names]
            twin = tuple(n for n in getattr(cls, "sign_twin", ()) if n in names)
            steps = [{n: v for n, v in st.items() if n in names} for st in flat[k]]
            modes = population_modes(
                members, fitness_, space.lower[idx], space.upper[idx], names, twin,
                [st for st in steps if st], np.asarray(x[k])[idx],
            )  # fmt: skip
        stages[f"stage{k + 1}"] = {
            **jac,
            "free": list(space.free),
            "modes": modes,
            "bound_hits": [
                h for h in bound_hits(sr.params, cls, search) if h["param"] in space.free
            ],  # fmt: skip
            "loo": loo[k],
            "loo_method": out.loo_method,
            "outliers": outliers(sr.residuals_mm, threshold),
        }
    space1 = spaces[0]
    cls1 = type(space1.template)
    stages["stage1"]["local_optima"] = population_modes(
        out.declared_params, out.declared_F, space1.lower, space1.upper, space1.free,
        tuple(n for n in getattr(cls1, "sign_twin", ()) if n in space1.free), flat[0],
        np.asarray(x[0]),
    )  # fmt: skip
    n = len(depth_mm)
    searched = out.refit_landmarks if out.refit_landmarks < n else 0
    return {
        "loss": {"name": loss.name, "scale_mm": float(loss_scale_mm)},
        "outlier_threshold_mm": threshold,
        **stages,
        "convention": convention_check(out.convention_F, declared, stage_results[0].F, searched),
    }
