"""The verdict of a calibration: which stage to deploy (by leave-one-out), the fit's
covariance under its noise model, and the touching error to expect from the stage chosen.

Everything here reads a result; nothing changes its parameters.
"""

from __future__ import annotations

import math
from dataclasses import replace

import jax.numpy as jnp
import numpy as np

from .._core import Stages
from ..calibration import (
    Deployment,
    Diagnostics,
    ExpectedError,
    FittedStage,
    LeaveOneOut,
    StageResult,
    is_ml,
    noise_part,
    prior_information,
)
from ..data import Observations
from ..problem import (
    NoiseFit,
    NoiseModel,
    StagePoint,
    std_dof,
    std_of_precision,
    uncertainty,
    workspace_targets,
)

#: Stage 2 is deployed only when its held-out hand error is lower than stage 1's by more than
#: this many standard errors of the paired difference (the simpler model otherwise).
DEPLOY_SE = 1.0
#: Hand angles of the verdict's targets, spread over the touches' range.
VERDICT_ANGLES = 8


def choose_stage(loo1: LeaveOneOut, loo2: LeaveOneOut, evidence: str = "leave-one-out",
                 rows: bool = False) -> Deployment:  # fmt: skip
    """The stage to deploy from each touch's held-out hand error under both stages.

    Stage 2 (ten more parameters) is chosen only when it predicts the held-out touches
    better than stage 1 by more than :data:`DEPLOY_SE` standard errors of the mean paired
    difference; else stage 1, the model alone.
    """
    h1 = np.array([h.hand_mm for h in loo1.held_out_mm])
    h2 = np.array([h.hand_mm for h in loo2.held_out_mm])
    k = len(h1)
    d = h2 - h1
    se = float(np.std(d, ddof=1) / math.sqrt(k)) if k > 1 else math.inf
    m1, m2, diff = float(h1.mean()), float(h2.mean()), float(d.mean())
    what = f"{k} touches held out one at a time, each refitted without it"
    if diff < -DEPLOY_SE * se:
        stage, why = 2, (f"stage 2 predicts held-out touches better: {m2:.3f} against {m1:.3f} "
                         f"mm ({what}; difference {diff:+.3f} ± {se:.3f} mm)")  # fmt: skip
    else:
        stage, why = 1, (f"stage 2 does not predict held-out touches better by more than its "
                         f"standard error: {m2:.3f} against stage 1's {m1:.3f} mm ({what}; "
                         f"difference {diff:+.3f} ± {se:.3f} mm), so the model alone")  # fmt: skip
    return Deployment(stage=stage, evidence=evidence, reason=why, stage1_mm=m1, stage2_mm=m2,
                      difference_se_mm=se if math.isfinite(se) else None, touches=k)  # fmt: skip


def ml_verdict(
    stages: Stages[FittedStage],
    diagnostics: Diagnostics,
    stage: int,
    noise: NoiseModel,
    obs: Observations,
    fits: Stages[NoiseFit | None] | None = None,
) -> tuple[Diagnostics, ExpectedError | None, np.ndarray | None]:
    """Under the noise model (both stages maximum-likelihood fits; else the diagnostics as
    they are and no expected error): each stage's standard deviations and precision in place
    of the paper's loss's Gauss–Newton ones (stage 2's with stage 1's uncertainty: it is
    fitted to stage 1's points) and, given each stage's ``fits`` (the noise scales its
    residuals gave), the degrees of freedom of each σ (:func:`std_dof`); the touching error
    ``stage`` makes over the calibration's own views touched at hand angles over the touches'
    range (:func:`workspace_targets`); and stage 1's covariance (``None`` with the diagnostics
    as they are)."""
    one, two = stages.stage1, stages.stage2
    if not (is_ml(one.objective) and is_ml(two.objective)):
        return diagnostics, None, None
    o1, o2 = noise_part(one.objective), noise_part(two.objective)
    P1, P2 = prior_information(one.space), prior_information(two.space)
    x1, x2 = jnp.asarray(one.x), jnp.asarray(two.x)
    targets = workspace_targets(obs, VERDICT_ANGLES)
    cov, infos, e = uncertainty(StagePoint(o1, x1, _j(P1)), targets, noise,
                                stage2=StagePoint(o2, x2, _j(P2)), stage=stage)  # fmt: skip
    cov = np.asarray(cov)
    d1 = len(x1)
    found = {}
    fits = Stages(None, None) if fits is None else fits
    for key, st, info, block, (o, x, P) in (
        ("stage1", one, infos[0], cov[:d1, :d1], (o1, x1, P1)),
        ("stage2", two, infos[1], cov[d1:, d1:], (o2, x2, P2)),
    ):
        info = np.asarray(info)
        undetermined = std_of_precision(info, st.space.free)
        std = {n: (None if undetermined[n] is None else float(math.sqrt(max(v, 0.0))))
               for n, v in zip(st.space.free, np.diag(block), strict=True)}  # fmt: skip
        fit = getattr(fits, key)
        dof = None
        if fit is not None:
            nu = std_dof(o, x, fit, P)
            dof = {n: (float(v) if np.isfinite(v) else None)
                   for n, v in zip(st.space.free, nu, strict=True) if std[n] is not None}
        found[key] = replace(getattr(diagnostics, key), std=std, std_dof=dof,
                             precision=tuple(tuple(r) for r in info.tolist()))  # fmt: skip
    angles = np.unique(np.asarray(targets.hand_angle_deg))
    views = targets.k // len(angles)
    captures = (1 if obs.capture_index is None
                else len(np.unique(np.asarray(obs.capture_index))))  # fmt: skip
    where = (f"{views} landmark views from the calibration's {captures} capture pose"
             f"{'s' if captures > 1 else ''}, each touched at hand angles "
             f"{angles.min():g} to {angles.max():g} deg")  # fmt: skip
    expected = ExpectedError(stage=stage, mean_mm=float(e.mean_mm), p95_mm=float(e.p95_mm),
                             targets=int(targets.k), where=where)  # fmt: skip
    return replace(diagnostics, **found), expected, cov[:d1, :d1]


def _j(P):
    return None if P is None else jnp.asarray(P)


def stage_noise(result: StageResult) -> NoiseModel | None:
    """The noise model a stage's maximum-likelihood fit ended with, or ``None``."""
    return None if result.noise is None else result.noise.noise
