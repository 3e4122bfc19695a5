"""A stage's fit as numbers: its F and residuals, its prior's pulls, its sign twin."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from .._core import InputError
from ..problem import (
    analyse_jacobian,
    std_of_precision,
)
from ._payloads import (
    PriorReport,
    Pull,
    Residual,
    SignTwin,
)
from ._programs import _error_jacobian, _report, _value
from ._result import StageResult
from ._stage import StageFit


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


def _finished(stage: StageFit, name: str, source: str | Path | None) -> StageResult:
    """A stage's fit as numbers, once it is finite (``source`` names the data if not)."""
    out = _stage_result(stage, _prior_report(stage))
    _check_finite(out, name, source)
    return out
