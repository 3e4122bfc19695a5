"""What the noise model says about a calibration's hand commands, before or after the fit.

The maximum-likelihood fit of each stage (:class:`~handeye_jax.NoiseObjective`) moves with the
noise ``ε`` of its whitened residuals (unit normal) as ``δθ₁ = −C₁ J₁ᵀ ε``, ``C₁ = (J₁ᵀJ₁ +
P₁)⁻¹``; stage 2, fitted to stage 1's points, as ``δθ₂ = −C₂ J₂ᵀ (T ε + K δθ₁)``, with ``K``
its residuals' Jacobian in stage 1's parameters and ``T`` taking stage 1's whitened noise to
stage 2's (the same pictures and touches). A hand command for a target then errs by ``Jc·δθ``
plus the target's own measurement noise: a 2-D normal error per target, whose mean length
and 95th percentile (over all targets) are the predicted touching error.

Everything here is JAX and differentiable: :func:`predict_command_error` takes a model, its
free parameters, the observations (a layout: where the landmarks are seen and touched), a
noise model and targets, and needs no data values beyond those.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._jax import fast_compile, in_float64
from ..data import Observations
from ..models import AbstractModel, AffinePair, Rig, Targets, hand_command
from ._noise import NoiseModel, NoiseObjective, noise_objective
from ._objective import Stage1Objective, Stage2Objective, chain_points, stage2_errors

#: Directions around the circle for a 2-D normal error's length statistics.
CIRCLE_POINTS = 64
#: The quantile of the touching error reported beside its mean.
QUANTILE = 0.95


class ErrorPrediction(eqx.Module):
    """A predicted hand-command error in x-y, mm.

    Attributes:
        mean_mm: the mean error length over the targets.
        p95_mm: the 95th percentile of the error length over the targets.
        per_target_mean_mm: each target's mean error length, ``(k,)``.
        covariance_mm2: each target's error covariance, ``(k, 2, 2)``.
    """

    mean_mm: Float[Array, ""]
    p95_mm: Float[Array, ""]
    per_target_mean_mm: Float[Array, " k"]
    covariance_mm2: Float[Array, "k 2 2"]


def _stage2_at(objective2: NoiseObjective, objective1: NoiseObjective, x1) -> NoiseObjective:
    """Stage 2's noise objective on the chain points of stage-1 parameters ``x1``."""
    base1: Stage1Objective = objective1.base
    points = chain_points(base1.model(x1), base1.obs)
    return eqx.tree_at(lambda o: o.base.points, objective2, points)


def _pinv(A):
    return jnp.linalg.pinv(0.5 * (A + A.T), hermitian=True)


def _noise_map_product(
    objective1: NoiseObjective, objective2: NoiseObjective, x2, J2: Float[Array, "r2 d2"]
) -> Float[Array, "d2 r1"]:
    """``J₂ᵀ T``, ``T`` taking stage 1's whitened noise to stage 2's (per row: a view's
    through A1's linear part and its x-y; a touch's x-y; heights have no stage 2), without
    forming ``T``."""
    n, k = objective1.touch_whitener.shape
    zero = jnp.zeros(2)
    model2 = objective2.base.model(x2)
    L1 = jax.jacfwd(lambda p: model2.first(p[None], zero)[0])(zero)
    pick = jnp.eye(2, k)
    Tv = jnp.einsum("nij,jk,kl,nlm->nim", objective2.view_whitener, L1, pick,
                    jnp.linalg.inv(objective1.view_whitener))  # fmt: skip
    w1 = objective1.touch_whitener[:, :2]
    Tt = jnp.einsum("ni,ij->nij", objective2.touch_whitener / jnp.where(w1 == 0, 1.0, w1), pick)
    d2 = J2.shape[1]
    Jv, Jt = J2[: 2 * n].reshape(n, 2, d2), J2[2 * n :].reshape(n, 2, d2)
    views = jnp.einsum("nid,nim->dnm", Jv, Tv).reshape(d2, n * k)
    touches = jnp.einsum("nid,nim->dnm", Jt, Tt).reshape(d2, n * k)
    return jnp.concatenate([views, touches], axis=1)


class StagePoint(NamedTuple):
    """One stage at a point of its parameters, as the predictions read it.

    Attributes:
        objective: the stage's objective under the noise model.
        x: the point (its optimum), the free parameters in their units.
        prior: the information a prior adds on the free parameters (``JᵀJ``'s units), or
            ``None``.
    """

    objective: NoiseObjective
    x: Float[Array, " d"]
    prior: Float[Array, "d d"] | None = None


def _point(stage: StagePoint | None) -> StagePoint | None:
    """``stage`` with its arrays as JAX float64 arrays (NumPy ones are accepted)."""
    if stage is None:
        return None
    prior = None if stage.prior is None else jnp.asarray(stage.prior, dtype=float)
    return StagePoint(stage.objective, jnp.asarray(stage.x, dtype=float), prior)


@in_float64
def noise_to_parameters(
    stage1: StagePoint, stage2: StagePoint | None = None
) -> tuple[Float[Array, "d1 r"], Float[Array, "d2 r"] | None]:
    """``(G₁, G₂)``: how each stage's parameters move with stage 1's whitened noise ``ε``
    (unit normal), ``δθ = G ε``; ``cov(θ₁, θ₂) = [G₁; G₂][G₁; G₂]ᵀ``."""
    return _gains(_point(stage1), _point(stage2))[:2]


def _gains(one: StagePoint, two: StagePoint | None):
    """``(G₁, G₂, A₁, A₂)``: :func:`noise_to_parameters`' gains and each stage's information
    (its prior's included; ``None`` for a stage not given)."""
    objective1, x1, prior1 = one
    objective2, x2, prior2 = (None, None, None) if two is None else two
    J1 = jax.jacfwd(objective1.whitened)(x1)
    A1 = J1.T @ J1 if prior1 is None else J1.T @ J1 + prior1
    G1 = -_pinv(A1) @ J1.T
    if objective2 is None:
        return G1, None, A1, None

    d1 = x1.shape[0]

    def r2(z):
        return _stage2_at(objective2, objective1, z[:d1]).whitened(z[d1:])

    JK = jax.jacfwd(r2)(jnp.concatenate([x1, x2]))
    K, J2 = JK[:, :d1], JK[:, d1:]
    A2 = J2.T @ J2 if prior2 is None else J2.T @ J2 + prior2
    G2 = -_pinv(A2) @ (_noise_map_product(objective1, objective2, x2, J2) + (J2.T @ K) @ G1)
    return G1, G2, A1, A2


@in_float64
def parameter_covariance(
    stage1: StagePoint, stage2: StagePoint | None = None
) -> Float[Array, "d d"]:
    """The fit's covariance: stage 1's free parameters, then stage 2's when given (their
    units², as ordered in each objective's ``free``)."""
    return _uncertainty(_point(stage1), _point(stage2), None, None, 1)[0]


@in_float64
def workspace_targets(obs: Observations, angles: int = 8, views: int = 64) -> Targets:
    """The targets a calibration's summary predicts for: the views in ``obs`` (their image
    points, depths and capture poses; at most ``views`` of them, spread over the rows),
    touched at ``angles`` hand angles evenly over the range of the touches' (one angle if
    they all share it)."""
    angle = np.asarray(obs.hand_angle_deg, dtype=float)
    lo, hi = float(angle.min()), float(angle.max())
    turns = np.array([lo]) if hi - lo < 1e-9 else np.linspace(lo, hi, angles)
    uv = np.asarray(obs.image_px, dtype=float)
    depth = np.asarray(obs.depth_mm, dtype=float)
    if obs.capture_position_mm is None:
        position = np.tile(np.asarray(obs.rig.capture_position_mm, float), (len(uv), 1))
        cap = np.full(len(uv), _capture_angle(obs.rig))
    else:
        position = np.asarray(obs.capture_position_mm, dtype=float)
        cap = np.asarray(obs.capture_hand_angle_deg, dtype=float)
    keys = np.round(np.column_stack([uv, depth, position, cap]), 9)
    _, first = np.unique(keys, axis=0, return_index=True)
    first = np.sort(first)
    if len(first) > views:
        first = first[np.round(np.linspace(0, len(first) - 1, views)).astype(int)]
    m = len(first)
    rep = lambda a: np.repeat(a[first], len(turns), axis=0)  # noqa: E731
    return Targets(jnp.asarray(rep(uv)), jnp.asarray(rep(depth)),
                   jnp.asarray(np.tile(turns, m)), jnp.asarray(rep(position)),
                   jnp.asarray(rep(cap)))  # fmt: skip


def _capture_angle(rig: Rig) -> float:
    """The rig's capture hand angle θc, deg (where φ = 0 when it has none)."""
    if rig.capture_hand_angle_deg is not None:
        return float(rig.capture_hand_angle_deg)
    return float(-float(rig.angle_zero_deg) * float(rig.angle_sign)) + 0.0


def _target_covariance(model, rig, targets: Targets, variances, correction=None,
                       centres=None) -> Float[Array, "k 2 2"]:  # fmt: skip
    """Each command's covariance from its target's own measurement (image point, depth;
    ``variances``: px², px², mm²)."""
    D = jnp.diag(variances)

    def one(uv, d, a, p, c):
        t = Targets(uv[None], d[None], a[None], p[None], c[None])

        def cmd(q):
            t2 = Targets(q[None, :2], q[2:], t.hand_angle_deg, t.capture_position_mm,
                         t.capture_hand_angle_deg)  # fmt: skip
            return hand_command(model, rig, t2, correction=correction, centres_mm=centres)[0, :2]

        return jax.jacfwd(cmd)(jnp.concatenate([uv, d[None]]))

    J = jax.vmap(one)(targets.image_px, targets.depth_mm, targets.hand_angle_deg,
                      targets.capture_position_mm, targets.capture_hand_angle_deg)  # fmt: skip
    return jnp.einsum("kij,jl,kml->kim", J, D, J)


def error_statistics(covariance_mm2: Float[Array, "k 2 2"]) -> tuple[Array, Array, Array]:
    """``(mean, p95, per-target mean)`` of the length of 2-D normal errors of these
    covariances, mm, the 95th percentile of their mixture over the targets.

    A normal ``e = L z`` has length ``r·|L u(φ)|`` with ``r`` Rayleigh and ``φ`` uniform,
    independent; both statistics are integrals over ``φ`` (:data:`CIRCLE_POINTS` points).
    """
    phi = jnp.arange(CIRCLE_POINTS) * (2.0 * math.pi / CIRCLE_POINTS)
    u = jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=1)
    s2 = jnp.einsum("pi,kij,pj->kp", u, covariance_mm2, u)
    s = jnp.sqrt(jnp.maximum(s2, 1e-300))
    per_target = math.sqrt(math.pi / 2.0) * jnp.mean(s, axis=1)

    def cdf(q):
        return jnp.mean(1.0 - jnp.exp(-(q**2) / (2.0 * s**2)))

    hi = 4.0 * jnp.max(s) + 1e-300

    def bisect(_, bounds):
        lo_, hi_ = bounds
        mid = 0.5 * (lo_ + hi_)
        below = cdf(mid) < QUANTILE
        return jnp.where(below, mid, lo_), jnp.where(below, hi_, mid)

    lo_, hi_ = jax.lax.fori_loop(0, 60, bisect, (jnp.zeros(()), hi))
    q = jax.lax.stop_gradient(0.5 * (lo_ + hi_))
    # One Newton step outside the loop: the quantile's gradient by the implicit function.
    dq = jax.grad(cdf)(q)
    q = q - (cdf(q) - QUANTILE) / jnp.where(dq > 0, dq, 1.0)
    return jnp.mean(per_target), q, per_target


@in_float64
def command_error(
    stage1: StagePoint,
    targets: Targets,
    noise: NoiseModel,
    *,
    stage2: StagePoint | None = None,
    stage: int = 1,
) -> ErrorPrediction:
    """The hand-command error ``stage`` (1: eq. 8; 2: eq. 25, which needs ``stage2``) makes
    for ``targets``: the fit's uncertainty (the noise through both stages, see the module)
    plus each target's own measurement (``noise``'s target σ and depth σ)."""
    return uncertainty(stage1, targets, noise, stage2=stage2, stage=stage)[2]


@in_float64
def uncertainty(
    stage1: StagePoint,
    targets: Targets,
    noise: NoiseModel,
    *,
    stage2: StagePoint | None = None,
    stage: int = 1,
) -> tuple[Float[Array, "d d"], tuple[Array, Array | None], ErrorPrediction]:
    """:func:`parameter_covariance` (both stages' when ``stage2`` is given), each stage's
    information (``(A₁, A₂)``, a prior's included; ``A₂`` ``None`` without stage 2) and
    :func:`command_error` of ``stage``, at once: one compiled program."""
    if stage not in (1, 2):
        raise ValueError(f"stage must be 1 or 2 (got {stage})")
    if stage == 2 and stage2 is None:
        raise ValueError("stage 2's error needs stage 2's objective and optimum")
    var_px, var_depth = noise.target_variances()
    variances = np.array([var_px, var_px, var_depth])
    return _uncertainty(_point(stage1), _point(stage2), targets, variances, stage)


def traced_command_error(
    stage1: StagePoint, targets: Targets, noise: NoiseModel
) -> ErrorPrediction:
    """Stage 1's :func:`command_error` as a plain JAX function, not compiled on its own: for
    use inside the caller's ``jax.grad`` or ``jax.jit`` (a compiled program with its own
    compiler options cannot be nested), e.g. to differentiate the error with respect to the
    observations' layout. ``stage1.prior`` is not used."""
    var_px, var_depth = noise.target_variances()
    variances = np.array([var_px, var_px, var_depth])
    one = StagePoint(stage1.objective, stage1.x)
    return _uncertainty.__wrapped__(one, None, targets, variances, 1)[2]


@fast_compile
def _uncertainty(one: StagePoint, two: StagePoint | None, targets, variances, stage: int):
    G1, G2, A1, A2 = _gains(one, two)
    objective1, x1 = one.objective, one.x
    G = G1 if G2 is None else jnp.concatenate([G1, G2], axis=0)
    cov = G @ G.T
    if targets is None:
        return cov, (A1, A2), None
    base1: Stage1Objective = objective1.base
    rig = base1.obs.rig
    if stage == 1:
        J = jax.jacfwd(lambda a: hand_command(base1.model(a), rig, targets)[:, :2])(x1)
        A = jnp.einsum("kid,dr->kir", J, G1)
        T = _target_covariance(base1.model(x1), rig, targets, variances)
    else:
        base2: Stage2Objective = two.objective.base
        x2 = two.x
        d1 = x1.shape[0]

        def cmd(z):
            model = base1.model(z[:d1])
            correction = base2.model(z[d1:])
            _, centres = stage2_errors(correction, chain_points(model, base1.obs),
                                       base2.centre_index)  # fmt: skip
            return hand_command(model, rig, targets, correction=correction,
                                centres_mm=centres)[:, :2], centres

        J, centres = jax.jacfwd(cmd, has_aux=True)(jnp.concatenate([x1, x2]))
        A = jnp.einsum("kid,dr->kir", J, G)
        T = _target_covariance(base1.model(x1), rig, targets, variances, base2.model(x2),
                               centres)  # fmt: skip
    C = jnp.einsum("kir,kjr->kij", A, A) + T
    mean, p95, per = error_statistics(C)
    return cov, (A1, A2), ErrorPrediction(mean, p95, per, C)


@in_float64
def predict_command_error(
    model: AbstractModel,
    free: Sequence[str],
    obs: Observations,
    noise: NoiseModel,
    targets: Targets,
    *,
    stage: int = 1,
) -> ErrorPrediction:
    """The touching error an acquisition gives, before it is taken (or after, at its fit).

    A fit with a prior, or stage 2 at other values or parameters, is :func:`command_error`
    of each stage's :class:`StagePoint`.

    Args:
        model: the stage-1 model the Jacobians are taken at (an approximate rig will do).
        free: the parameters the fit moves.
        obs: the observations' layout: views (image points, depths, capture poses) and
            touches (hand angles); their measured values do not matter, only where they are.
        noise: the noise model.
        targets: the points to predict for.
        stage: 1, or 2 with the affine correction at the identity, all ten parameters free.
    """
    free = tuple(free)
    x1 = jnp.stack([jnp.asarray(getattr(model, n), dtype=float) for n in free])
    one = StagePoint(noise_objective(Stage1Objective(model, obs, free), noise, model), x1)
    two = None
    if stage == 2:
        correction = AffinePair.nominal()
        free2 = type(correction).param_names
        x2 = jnp.stack([jnp.asarray(getattr(correction, n), dtype=float) for n in free2])
        base2 = Stage2Objective(correction, chain_points(model, obs), obs.centre_index, free2)
        two = StagePoint(noise_objective(base2, noise, model, obs), x2)
    return command_error(one, targets, noise, stage2=two, stage=stage)


@in_float64
def fisher_information(objective: NoiseObjective, x: Float[Array, " d"]) -> Float[Array, "d d"]:
    """``JᵀJ`` of the whitened residuals at ``x``: the data's information on the free
    parameters (a prior's is added apart)."""
    return _information(objective, jnp.asarray(x))


@fast_compile
def _information(objective, x):
    J = jax.jacfwd(objective.whitened)(x)
    return J.T @ J
