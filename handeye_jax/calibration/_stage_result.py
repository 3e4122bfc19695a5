"""A stage's fit as numbers: its F and residuals, its prior's pulls, its sign twin."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._core import InputError
from .._jax import single_device_mesh
from ..optim import Box, minimise_many
from ..problem import (
    AbstractObjective,
    analyse_jacobian,
    fisher_information,
    std_of_precision,
)
from ._likelihood import is_ml, noise_part
from ._payloads import (
    PriorReport,
    Pull,
    Residual,
    SignTwin,
)
from ._programs import stage_error_jacobian, stage_report, stage_value
from ._result import StageResult
from ._search import stack
from ._stage import POLISH, StageFit
from ._warnings import PULL_FLAG


def _prior_report(stage: StageFit) -> PriorReport | None:
    """The prior of a stage and how far the data pulled each parameter from it.

    With ``d = θ − μ`` the fit's move from the prior mean and ``Q = Σ_prior − Σ_post`` its
    covariance when the prior is right, the pull of parameter j is Baarda's w-test of a shift
    of μ_j alone, ``(Q⁻¹d)_j/√(Q⁻¹)_jj``: standard normal for a right prior, and largest for
    the parameter that moved even when correlated ones absorb part of its move (the marginal
    ``d_j/√Q_jj``, kept as ``marginal_pull``, then blames them). Each tested parameter the
    new data inform (``(Q⁻¹)_jj > 0``) then gets the test's likelihood-ratio form, from refits
    (:func:`_released_pulls`): the linear one, taken at a fit a wrong prior has dragged, can
    be at the noise for the parameter that moved. ``Σ_post`` is the Gauss–Newton
    posterior ``(JᵀJ/σ² + Σ_prior⁻¹)⁻¹`` at the fit, with the noise σ of the fit the prior came
    from when the prior states it: a few new landmarks leave too few degrees of freedom to
    estimate σ (benchmarks/RESULTS.md, "Recalibration: what three touches can reach").
    """
    space = stage.space
    prior = space.prior
    if prior is None:
        return None
    idx = list(space.prior_indices())
    P_full = np.zeros((space.d, space.d))
    P_full[np.ix_(idx, idx)] = prior.precision
    if is_ml(stage.objective):  # the noise model's information: the prior's own
        P_post = np.asarray(fisher_information(noise_part(stage.objective),
                                               jnp.asarray(stage.x))) + P_full  # fmt: skip
    elif prior.data_sigma_mm is not None:
        e, J = (np.asarray(a) for a in stage_error_jacobian(stage.data, stage.x))
        P_post = J.T @ J / prior.data_sigma_mm**2 + P_full
    else:
        e, J = (np.asarray(a) for a in stage_error_jacobian(stage.data, stage.x))
        P_post = np.asarray(analyse_jacobian(e, J, space.free, ["1"] * space.d, None,
                                             P_full).precision)  # fmt: skip
    post = std_of_precision(P_post, space.free)
    Q = prior.covariance() - np.linalg.pinv(P_post, hermitian=True)[np.ix_(idx, idx)]
    Q_inv = _update_precision(Q, prior.precision)
    d = stage.x[idx] - prior.mean
    sig_prior = prior.sigma
    pulls = np.array([(Q_inv[j] @ d) / math.sqrt(Q_inv[j, j]) if Q_inv[j, j] > 0 else 0.0
                      for j in range(len(prior.names))])  # fmt: skip
    # All of them, not only those the linear pull flags: at a fit a wrong prior dragged, it
    # can miss the one that moved (RESULTS.md, "The pull of every tested parameter by refits").
    tested = [j for j, n in enumerate(prior.names) if n not in prior.untested and Q_inv[j, j] > 0]
    follows = {}
    if tested:
        pulls, follows = _released_pulls(stage, pulls, tested)
    out = []
    for j, name in enumerate(prior.names):
        sp, spost = float(sig_prior[j]), post[name]
        marginal = d[j] / math.sqrt(Q[j, j]) if Q[j, j] > 0 else 0.0
        out.append(Pull(
            param=name, mean=float(prior.mean[j]), sigma=sp if math.isfinite(sp) else None,
            value=float(stage.x[idx[j]]), posterior_sigma=spost, pull=float(pulls[j]),
            marginal_pull=float(marginal), follows=follows.get(name),
        ))  # fmt: skip
    return PriorReport(
        source=prior.source, names=tuple(prior.names), mean=tuple(prior.mean.tolist()),
        precision=tuple(tuple(row) for row in prior.precision.tolist()),
        data_scale_mm=prior.data_scale_mm, pulls=tuple(out), data_sigma_mm=prior.data_sigma_mm,
        untested=tuple(prior.untested), alternatives=tuple(prior.alternatives),
    )  # fmt: skip


#: The pulls test the directions in which the new data explain at least this fraction of the
#: prior's variance; in the others the fit stays at the prior's mean, and ``Q`` is round-off.
INFORMED_FRACTION = 0.05


def _update_precision(Q: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``Q⁺`` on the directions the new data inform: with ``P`` the prior's precision, the
    eigenvalues λ of ``P^½ Q P^½`` are the fractions of the prior's variance the data explain
    (0 to 1); directions with λ below :data:`INFORMED_FRACTION` are left out."""
    w, U = np.linalg.eigh(0.5 * (P + P.T))
    root = (U * np.sqrt(np.maximum(w, 0.0))) @ U.T
    lam, V = np.linalg.eigh(root @ (0.5 * (Q + Q.T)) @ root)
    keep = lam > INFORMED_FRACTION
    A = root @ V[:, keep]
    return (A / lam[keep]) @ A.T


def _moved_prior(stage: StageFit, shift: np.ndarray, at_prior: np.ndarray):
    """The stage's objective with its prior's mean moved by ``shift``, LM's starts for it (the
    fit, and the moved mean with the other parameters at the fit) and its lowest value."""
    prior = stage.space.prior
    moved = eqx.tree_at(lambda o: o.mean, stage.objective, jnp.asarray(prior.mean + shift))
    start = np.array(at_prior, dtype=float)
    start[list(stage.space.prior_indices())] += shift
    starts = [np.asarray(stage.x), stage.space.clip(start)]
    return moved, starts, _lowest(stage, moved, starts)[0]


def _refit_released(
    stage: StageFit, cols: list[int], starts: list[np.ndarray],
    objective: AbstractObjective | None = None,
) -> tuple[float, np.ndarray]:  # fmt: skip
    """The stage's lowest value and its point, by LM from each of ``starts``, with the prior
    means of the prior's parameters ``cols`` free: the prior's precision ``P`` becomes
    ``P − PE(EᵀPE)⁻¹EᵀP`` (``E``: those columns of the identity), the prior's information about
    everything else kept. Every refit of a stage runs one LM program (its objective differs
    from the fit's in the whitener's and the mean's values alone). ``objective``: the stage's
    with its prior's mean moved (default: the stage's own)."""
    prior = stage.space.prior
    P = prior.precision
    E = np.eye(len(P))[:, cols]
    A = np.eye(len(P)) - E @ np.linalg.solve(E.T @ P @ E, E.T @ P)
    objective = eqx.tree_at(lambda o: o.whitener, objective or stage.objective,
                            jnp.asarray(prior.whitener() @ A))  # fmt: skip
    return _lowest(stage, objective, starts)


def _lowest(stage: StageFit, objective: AbstractObjective,
            starts: list[np.ndarray]) -> tuple[float, np.ndarray]:  # fmt: skip
    best = (math.inf, starts[0])
    for x0 in starts:
        value, x = _lm_from(stage, objective, x0)
        if np.isfinite(value) and value < best[0]:
            best = (value, x)
    return best


def _lm_from(stage: StageFit, objective: AbstractObjective,
             x0: np.ndarray) -> tuple[float, np.ndarray]:  # fmt: skip
    """LM (:data:`POLISH`) on ``objective``, of the stage's structure, from ``x0``: its value
    and end point."""
    space = stage.space
    box = Box(space.lower[None], space.upper[None])
    lm = minimise_many(stack([objective]), POLISH, box, x0=np.asarray(x0)[None],
                       mesh=single_device_mesh())  # fmt: skip
    return float(lm.value[0]), np.asarray(lm.x[0])


def _released_pulls(stage: StageFit, pulls: np.ndarray,
                    tested: list[int]) -> tuple[np.ndarray, dict[str, str]]:  # fmt: skip
    """The ``tested`` parameters' pulls as likelihood ratios, and which of the flagged ones
    follow another (``pulls``: the linear ones, kept for the others).

    Parameter j's pull becomes ``±√(2ΔF/w)``: ΔF is how far the stage's value drops when the
    fit is redone with μ_j free (``w``: the prior block's weight, so ``2ΔF/w`` is the drop of
    −2 log posterior, χ²₁ when the prior is right), signed by where that refit puts the
    parameter against μ_j. In the linear limit this is the w-test; unlike it, it stays right
    when a wrong prior has moved the fit far (its sign too). Each refit starts from the fit
    and from the prior's mean (a wrong prior can drag the fit across a fold, such as the
    tablet's tilt signs, that LM from the fit does not cross back).

    Then data snooping, a step at a time: the flagged parameter pulled most is freed for good,
    and each other flagged one is tested again with the freed ones' means free. One whose pull
    is no longer flagged follows the parameter freed last; of the rest, the one pulled most
    is freed next (a second parameter that moved), until none is left."""
    prior = stage.space.prior
    weight = float(stage.objective.weight)
    idx = list(stage.space.prior_indices())
    at_prior = np.array(stage.x, dtype=float)
    at_prior[idx] = prior.mean
    at_prior = stage.space.clip(at_prior)
    # The fit's own value as these refits reach it (LM from the fit), so that the drops
    # compare optimum with optimum.
    F0, _ = _lm_from(stage, stage.objective, stage.x)

    out = np.array(pulls, dtype=float)
    # The priors a pull is tested from: the prior, and the prior moved to each fit its old
    # data could not exclude (objective, starts, lowest value); each tested parameter's
    # release from each of them (value and point).
    references = [(stage.objective, [stage.x, at_prior], F0)]
    references += [_moved_prior(stage, shift, at_prior) for shift in prior.alternative_shifts()]
    F_ref = [F for _, _, F in references]
    released = {}
    for j in tested:
        released[j] = [_refit_released(stage, [j], starts, objective)
                       for objective, starts, _ in references]  # fmt: skip
        # The rig may have been at a fit its old data could not tell from the prior's mean:
        # the pull is the smallest of those from the prior and from the prior moved there; its
        # sign, where the data put μ_j (released from the prior itself) against its mean.
        toward = released[j][0][1][idx[j]] - prior.mean[j]
        out[j] = math.copysign(_smallest_pull(F_ref, _values(released[j]), weight), toward)
    follows = {}
    left = {j: abs(out[j]) for j in tested if abs(out[j]) > PULL_FLAG}
    freed: list[int] = []
    while left:
        top = max(left, key=left.get)
        freed.append(top)
        base = released[top]
        del left[top]
        for i in list(left):
            released[i] = [_refit_released(stage, [*freed, i], [x1, starts[-1]], objective)
                           for (objective, starts, _), (_, x1)
                           in zip(references, base, strict=True)]  # fmt: skip
            left[i] = _smallest_pull(_values(base), _values(released[i]), weight)
            if left[i] <= PULL_FLAG:
                follows[prior.names[i]] = prior.names[top]
                del left[i]
    return out, follows


def _pull(drop: float, weight: float) -> float:
    """The likelihood-ratio pull of a drop of the stage's value (see :func:`_released_pulls`)."""
    return math.sqrt(max(2.0 * drop / weight, 0.0))


def _smallest_pull(before: list[float], after: list[float], weight: float) -> float:
    """The smallest pull over the reference priors, from each one's lowest value ``before`` a
    release to its value ``after`` it."""
    return min(_pull(b - a, weight) for b, a in zip(before, after, strict=True))


def _values(refits: list[tuple[float, np.ndarray]]) -> list[float]:
    return [F for F, _ in refits]


def _stage_result(stage: StageFit, prior_report: PriorReport | None = None) -> StageResult:
    errors, (F, f1, f2), (n1, n2), value, terms = stage_report(stage.objective, stage.x)
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


def sign_twin_of(stage: StageFit) -> SignTwin | None:
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
        F_found_mm=stage_value(stage.data, stage.x), F_flipped_mm=stage_value(stage.data, flipped),
        note="flipping the signs of " + " and ".join(names) + " together mirrors the tablet "
        "through its own plane and gives the same F",
    )  # fmt: skip


def finished_stage(stage: StageFit, name: str, source: str | Path | None) -> StageResult:
    """A stage's fit as numbers, once it is finite (``source`` names the data if not)."""
    out = _stage_result(stage, _prior_report(stage))
    _check_finite(out, name, source)
    return out
