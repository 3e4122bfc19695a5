"""The noise model of the data, and the fit's likelihood under it.

What a calibration measures, and how each measurement strays (:class:`NoiseModel`):

* each **picture** (a capture) gives every landmark it shows an image point ``(u, v)`` and a
  depth; their errors (``image_sigma_px`` per axis, ``depth_sigma_mm``) move that view's
  back-projected point ``x_bi`` in the base frame by a 3-D error whose covariance follows from
  the chain's Jacobian in ``(u, v, depth)``;
* each **touch** gives a hand position, rounded by the controller (``hand_resolution_mm``, a
  uniform error of σ = r/√12 per axis), and a touch error reported by the tablet in whole
  tablet px (``tablet_resolution_px``) plus what the tablet cannot see (``touch_sigma_mm``:
  the pen's contact against its tip).

A row of the objective pairs a view with a touch (:class:`~handeye_jax.Observations`). The
paper's two error vectors of a row share the view's noise (``f1 = x_bi − x_bt``, ``f2 = x_bi −
x' − x_r'``), and with several captures one touch is paired with each view of its landmark.
Counted as independent, a touch seen from three captures enters three times. Here the
residuals are separated so that each noise source enters once: the **view** residual ``x_bi −
x_bt`` carries the picture's noise, the **touch** residual ``x_bt − x' − x_r'`` (stage 2:
``A2(x_bt − x') − x_r'``, which is ``f2 − L2·f1``) the touch's; each is whitened by its own
covariance and divided by the number of rows that repeat it. The sum of their squares is −2
log-likelihood (up to a constant): :class:`NoiseObjective` is the maximum-likelihood
objective, and ``(JᵀJ)⁻¹`` of its whitened Jacobian the fit's covariance.

The scales of the noise are estimated from the data (:func:`estimate_noise`, restricted
maximum likelihood: each component's sum of squares over its redundancy), starting from a
preset (:data:`NOISE_MODELS`): the touches' scale, and the pictures' — one for the image and
the depth together, or one each where the views' residuals tell them apart (recorded hand
heights give the views a z, which sees the depth directly). Dots of two pixels are found twice
as precisely as the preset's one-pixel dots while the depth's error stays as it was: one
shared scale then weights the depth too little or the image too much.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core import spec
from .._jax import fast_compile, in_float64
from ..data import Observations
from ..models import AbstractModel
from ._objective import (
    AbstractObjective,
    GaussianBlock,
    Stage1Objective,
    Stage2Objective,
    chain_points,
    stage2_errors,
)

#: A group's variance scale is estimated only when its redundancy is at least this.
MIN_REDUNDANCY = 2.0
#: Scales never fall below this (noise-free data would otherwise give infinite weights).
MIN_SCALE = 1e-12


@dataclass(frozen=True)
class NoiseModel:
    """How far each measurement strays (independent, Gaussian; per axis).

    Attributes:
        image_sigma_px: a landmark's image point ``(u, v)``, each axis, px.
        depth_sigma_mm: the depth read at it, mm.
        hand_resolution_mm: the controller reports hand positions rounded to this, mm (a
            uniform error, σ = r/√12 per axis, x, y and z); 0: exact.
        touch_sigma_mm: the part of a touch's error the tablet does not report (the pen's
            contact against its tip), each axis, mm.
        tablet_resolution_px: the tablet reports the touch error rounded to this, tablet px.
        target_sigma_px: a target's image point as the user measures it, each axis, px
            (``None``: ``image_sigma_px``); for predicted hand-command errors.
        view_scale, touch_scale: variance multipliers of the pictures' and the touches'
            noise, estimated from a fit's residuals (:func:`estimate_noise`); 1: as stated.
        depth_scale: the depth's own variance multiplier, where the data tell it apart from
            the image's (``None``: ``view_scale`` applies to the depth too).
        name: the preset's name, or ``"custom"``.
    """

    image_sigma_px: float = 0.1
    depth_sigma_mm: float = 0.3
    hand_resolution_mm: float = 1.0
    touch_sigma_mm: float = 0.0
    tablet_resolution_px: float = 1.0
    target_sigma_px: float | None = None
    view_scale: float = 1.0
    touch_scale: float = 1.0
    name: str = "custom"
    depth_scale: float | None = spec(omit="none", default=None)

    def __post_init__(self):
        for f in ("image_sigma_px", "depth_sigma_mm", "hand_resolution_mm", "touch_sigma_mm",
                  "tablet_resolution_px", "view_scale", "touch_scale"):  # fmt: skip
            v = getattr(self, f)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{f} must be finite and >= 0 (got {v})")
        d = self.depth_scale
        if d is not None and not (math.isfinite(d) and d >= 0):
            raise ValueError(f"depth_scale must be finite and >= 0 or None (got {d})")
        if self.image_sigma_px + self.depth_sigma_mm <= 0:
            raise ValueError("a picture's noise (image_sigma_px, depth_sigma_mm) must not be 0")
        if self.hand_resolution_mm + self.touch_sigma_mm + self.tablet_resolution_px <= 0:
            raise ValueError("a touch's noise (hand_resolution_mm, touch_sigma_mm, "
                             "tablet_resolution_px) must not be 0")  # fmt: skip

    def touch_variance_mm2(self, mm_per_tablet_px: float) -> float:
        """A touch's error variance per axis (x, y), mm²: the hand's rounding, the tablet's
        rounding of the touch error and what it does not see, times ``touch_scale``."""
        v = (self.hand_resolution_mm**2 / 12.0 + self.touch_sigma_mm**2
             + (self.tablet_resolution_px * mm_per_tablet_px) ** 2 / 12.0)  # fmt: skip
        return self.touch_scale * v

    def hand_z_variance_mm2(self) -> float:
        """A recorded hand height's error variance, mm² (its rounding, times
        ``touch_scale``; at least a tenth of the x-y variance's floor)."""
        return self.touch_scale * max(self.hand_resolution_mm**2 / 12.0, 1e-6)

    @property
    def depth_scale_or_view(self) -> float:
        """The depth's variance multiplier: ``depth_scale``, or ``view_scale`` if shared."""
        return self.view_scale if self.depth_scale is None else self.depth_scale

    def picture_variances(self) -> tuple[float, float]:
        """``(image px², depth mm²)``: a view's variances, times their scales."""
        return (self.view_scale * self.image_sigma_px**2,
                self.depth_scale_or_view * self.depth_sigma_mm**2)  # fmt: skip

    def target_variances(self) -> tuple[float, float]:
        """``(image px², depth mm²)`` of a target measured by the user."""
        s = self.image_sigma_px if self.target_sigma_px is None else self.target_sigma_px
        return self.view_scale * s**2, self.depth_scale_or_view * self.depth_sigma_mm**2

    def scaled(self, view: float = 1.0, touch: float = 1.0, depth: float | None = None
               ) -> NoiseModel:  # fmt: skip
        """The model with its pictures' and touches' variances multiplied by these (the
        depth's by ``depth``, default ``view``; a shared scale stays shared unless ``depth``
        is given)."""
        if depth is None and self.depth_scale is None:
            depth_scale = None
        else:
            depth_scale = max(self.depth_scale_or_view * (view if depth is None else depth),
                              MIN_SCALE)  # fmt: skip
        return replace(self, view_scale=max(self.view_scale * view, MIN_SCALE),
                       touch_scale=max(self.touch_scale * touch, MIN_SCALE),
                       depth_scale=depth_scale)  # fmt: skip

    def effective(self, mm_per_tablet_px: float) -> dict[str, float]:
        """The σs the scales give, per axis: image px, depth mm and a touch's x-y mm."""
        image, depth = self.picture_variances()
        return {"image_px": math.sqrt(image), "depth_mm": math.sqrt(depth),
                "touch_mm": math.sqrt(self.touch_variance_mm2(mm_per_tablet_px))}  # fmt: skip


#: The presets. ``paper``: the `paper` twin's measured noise (benchmarks/RESULTS.md, "The
#: noise model"): detected landmark centroids 0.10 px per axis (one-pixel dots), depths read
#: from a 1-mm-step depth image 0.30 mm, hand positions in whole mm, touch errors in whole
#: tablet px; targets measured to 0.15 px.
NOISE_MODELS: dict[str, NoiseModel] = {
    "paper": NoiseModel(image_sigma_px=0.1, depth_sigma_mm=0.3, hand_resolution_mm=1.0,
                        touch_sigma_mm=0.0, tablet_resolution_px=1.0, target_sigma_px=0.15,
                        name="paper"),  # fmt: skip
}


def get_noise_model(name: str) -> NoiseModel:
    """The preset called ``name`` (one of :data:`NOISE_MODELS`)."""
    try:
        return NOISE_MODELS[name]
    except KeyError:
        known = ", ".join(NOISE_MODELS)
        raise ValueError(f"unknown noise model {name!r}; known: {known}") from None


# -- the rows as views and touches ---------------------------------------------------------


def _counts(keys: np.ndarray) -> np.ndarray:
    """How many rows share each row's key (rows of ``keys``)."""
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    return counts[inverse.reshape(-1)].astype(float)


def row_counts(obs: Observations) -> tuple[np.ndarray, np.ndarray]:
    """For each row, how many rows repeat its view (the same capture's picture of the same
    landmark) and its touch: ``(view_count, touch_count)``, ``(n,)`` each. The paper's single
    capture gives ones."""
    n = obs.n_landmarks
    if obs.capture_index is None or obs.touch_index is None:
        return np.ones(n), np.ones(n)
    capture = np.asarray(obs.capture_index, dtype=float)[:, None]
    landmark = np.round(np.asarray(obs.tablet_mm, dtype=float), 9)
    view = _counts(np.concatenate([capture, landmark], axis=1))
    touch = _counts(np.asarray(obs.touch_index)[:, None])
    return view, touch


def touch_groups(obs: Observations) -> np.ndarray:
    """Each row's touch, numbered 0, 1, … in touch order: the rows a leave-one-out leaves out
    together (a touch seen from three captures is three rows). The paper's single capture
    gives ``0 … n−1``."""
    if obs.touch_index is None:
        return np.arange(obs.n_landmarks)
    return np.unique(np.asarray(obs.touch_index), return_inverse=True)[1].reshape(-1)


def view_covariance(
    model: AbstractModel, obs: Observations, noise: NoiseModel, dims: int = 2
) -> Float[Array, "n k k"]:
    """Each row's view error covariance in the base frame, mm², ``(n, dims, dims)``: the
    image point's and the depth's noise through the back-projection of eq. (5), x and y (and
    z with ``dims = 3``)."""
    image_var, depth_var = noise.picture_variances()
    return fast_compile(_view_covariance)(model, obs, np.array([image_var, image_var, depth_var]),
                                          dims)  # fmt: skip


def _view_covariance(model, obs: Observations, variances, dims: int):
    D = jnp.diag(variances)
    pos = obs.capture_position_mm
    phi = obs.capture_phi_deg()

    def one(uv, d, p, f):
        def x_bi(a):
            if p is None:
                return model.image_to_base(a[None, :2], a[2:], obs.rig)[0]
            return model.image_to_base(a[None, :2], a[2:], obs.rig, p[None], f[None])[0]

        return jax.jacfwd(x_bi)(jnp.concatenate([uv, d[None]]))[:dims]

    if pos is None:
        J = jax.vmap(lambda uv, d: one(uv, d, None, None))(obs.image_px, obs.depth_mm)
    else:
        J = jax.vmap(one)(obs.image_px, obs.depth_mm, pos, phi)
    return jnp.einsum("nij,jk,nlk->nil", J, D, J)


@fast_compile
def _view_whitener(model, obs: Observations, variances, view_count, dims: int):
    """Each row's view whitener ``W`` (``WᵀW = S⁻¹/count``) and, for views with a z, the
    image's share of its whitened covariance, ``LᵀS_image L`` (``LLᵀ = S⁻¹``; the depth's is
    ``I`` less it; zeros without a z, where the scales are not told apart): one compiled
    program."""
    S = _view_covariance(model, obs, variances, dims)
    L = jnp.linalg.cholesky(jnp.linalg.inv(S))
    Lt = jnp.swapaxes(L, -1, -2)
    W = Lt / jnp.sqrt(view_count)[:, None, None]
    if dims < 3:  # x-y only: W's program as it was, bit for bit
        return W, jnp.zeros_like(S)
    S_image = _view_covariance(model, obs, variances.at[2].set(0.0), dims)
    return W, Lt @ S_image @ L


# -- the objective ---------------------------------------------------------------------------


class NoiseObjective(AbstractObjective):
    """A stage's objective under a noise model: blocks ``views`` and ``touches``, each row's
    separated residual whitened (see the module); their value is ``χ²/n``, ``χ²`` the sum of
    squares of :meth:`whitened`: −2 log-likelihood up to a constant.

    Build it with :func:`noise_objective`.

    Attributes:
        base: the paper's stage objective (:class:`~handeye_jax.Stage1Objective` or
            :class:`~handeye_jax.Stage2Objective`), whose errors are separated.
        view_whitener: per row, ``(k, k)``, k = 2 (x-y) or 3 (with the hand's heights).
        touch_whitener: per row and axis, ``(k,)`` (0 for a height not recorded).
        image_share: per row, ``(k, k)``: the image noise's part of the whitened view
            residual's covariance (the depth's is the identity less it), for estimating
            their scales apart (:func:`estimate_noise`).
    """

    base: AbstractObjective
    view_whitener: Float[Array, "n k k"]
    touch_whitener: Float[Array, "n k"]
    image_share: Float[Array, "n k k"]

    def separated(self, theta) -> tuple[Float[Array, "n k"], Float[Array, "n k"]]:
        """The rows' view and touch residuals at ``theta``, mm (not whitened)."""
        return separated_errors(self.base, theta)

    def whitened(self, theta) -> Float[Array, " r"]:
        """Every row's whitened view residual, then every row's whitened touch residual."""
        v, t = self._whitened(theta)
        return jnp.concatenate([v.reshape(-1), t.reshape(-1)])

    def _whitened(self, theta):
        v, t = self.separated(theta)
        if v.shape[1] == 3:
            v = v.at[:, 2].add(-view_offset(self.view_whitener, v))
        return jnp.einsum("nij,nj->ni", self.view_whitener, v), t * self.touch_whitener

    def blocks(self, theta):
        v, t = self._whitened(theta)
        one = jnp.ones(v.shape[0])
        return {"views": GaussianBlock(v, jnp.asarray(1.0), one),
                "touches": GaussianBlock(t, jnp.asarray(1.0), one)}  # fmt: skip

    def on_landmarks(self, idx):
        idx = np.asarray(idx)
        return NoiseObjective(self.base.on_landmarks(idx), self.view_whitener[idx],
                              self.touch_whitener[idx], self.image_share[idx])  # fmt: skip


def view_offset(view_whitener: Float[Array, "n 3 3"], view: Float[Array, "n 3"]) -> Array:
    """The views' common z offset (the camera's height on the hand, which the models do not
    carry) by generalised least squares under their covariances, mm.

    The views' z residuals arrive less their plain mean. With the hand's heights a view's
    whitener mixes its z into its x and y (a depth error also moves the back-projected point
    sideways, often more than its own pixel noise does), so that mean's error, common to
    every row, reached each row's whitened x-y many times over: on a 3-capture grid of 147
    views it showed as about 15 extra degrees of χ², most of them in the image's share, and
    depth noise alone was estimated as image noise. Weighted by the covariances, the offset is
    the likelihood's own profile, and it is one fitted parameter (:func:`estimate_noise`).
    """
    M = jnp.einsum("nki,nkj->nij", view_whitener, view_whitener)  # each row's S⁻¹/count
    return jnp.sum(jnp.einsum("nj,nj->n", M[:, 2], view)) / jnp.sum(M[:, 2, 2])


def separated_errors(
    base: AbstractObjective, theta
) -> tuple[Float[Array, "n k"], Float[Array, "n k"]]:
    """A stage's rows split by noise source, mm: the view residual (``x_bi − x_bt``, stage
    2: ``A1(x_bi) − x_bt``) and the touch residual (``x_bt − x' − x_r'``, stage 2:
    ``A2(x_bt − x') − x_r'``); with the hand's heights, each with its z (less the profiled
    offset; 0 where a touch recorded none)."""
    if isinstance(base, Stage2Objective):
        model = base.model(theta)
        errors, _ = stage2_errors(model, base.points, base.centre_index)
        zero = jnp.zeros(2)
        L2 = jax.jacfwd(lambda p: model.second(p[None], zero)[0])(zero)
        e1 = errors.image_vs_tablet
        return e1, errors.hand - e1 @ L2.T
    if not isinstance(base, Stage1Objective):
        raise TypeError(f"expected a stage objective, got {type(base).__name__}")
    p = chain_points(base.model(theta), base.obs)
    view = p.image_xy - p.tablet_xy
    touch = p.tablet_xy - p.pen_offset_xy - p.hand_target_xy
    if p.hand_z is None:
        return view, touch
    z1 = p.image_z - p.tablet_z
    z2 = p.hand_z - p.tablet_z - p.touched_z
    ok = jnp.isfinite(z2)
    z2 = jnp.where(ok, z2, 0.0)
    z2 = jnp.where(ok, z2 - jnp.sum(z2) / jnp.sum(ok), 0.0)
    return (jnp.concatenate([view, (z1 - jnp.mean(z1))[:, None]], axis=1),
            jnp.concatenate([touch, z2[:, None]], axis=1))  # fmt: skip


def _stage_obs(base: AbstractObjective, obs: Observations | None) -> Observations:
    if isinstance(base, Stage1Objective):
        return base.obs
    if obs is None:
        raise ValueError("stage 2's noise objective needs the observations of its stage 1")
    return obs


def noise_objective(
    base: AbstractObjective,
    noise: NoiseModel,
    model: AbstractModel | None = None,
    obs: Observations | None = None,
) -> NoiseObjective:
    """``base`` (the paper's stage objective) under ``noise``.

    Args:
        base: a :class:`~handeye_jax.Stage1Objective` or :class:`~handeye_jax.Stage2Objective`.
        noise: the noise model.
        model: the stage-1 model the views' covariances are taken at (default: stage 1's
            template; the covariances depend on it only through the camera's orientation).
        obs: the observations (stage 2's; stage 1's are its own).
    """
    obs = _stage_obs(base, obs)
    if model is None:
        if not isinstance(base, Stage1Objective):
            raise ValueError("stage 2's noise objective needs the stage-1 model")
        model = base.template
    heights = isinstance(base, Stage1Objective) and obs.hand_z_mm is not None
    dims = 3 if heights else 2
    view_count, touch_count = row_counts(obs)
    image_var, depth_var = noise.picture_variances()
    W, share = _view_whitener(model, obs, np.array([image_var, image_var, depth_var]), view_count,
                              dims)  # fmt: skip
    var_xy = noise.touch_variance_mm2(_mm_per_tablet_px(obs))
    w = np.tile(1.0 / np.sqrt(var_xy * touch_count)[:, None], (1, dims))
    if heights:
        recorded = np.isfinite(np.asarray(obs.hand_z_mm))
        w[:, 2] = np.where(recorded, 1.0 / np.sqrt(noise.hand_z_variance_mm2() * touch_count), 0.0)
    return NoiseObjective(base, W, jnp.asarray(w), share)


#: The tablet px size of observations that do not carry theirs: the paper's tablet, mm.
PAPER_MM_PER_TABLET_PX = 25.4 / 267.0 * 2.0


def _mm_per_tablet_px(obs: Observations) -> float:
    """The tablet px size the observations' touch errors were converted with, mm."""
    mm = obs.mm_per_tablet_px
    return PAPER_MM_PER_TABLET_PX if mm is None else float(mm)


# -- estimating the scales -------------------------------------------------------------------


@fast_compile
def whitened_jacobian(objective: NoiseObjective, theta) -> tuple[Array, Array]:
    """The whitened residuals at ``theta`` and their Jacobian (one compiled program)."""
    return objective.whitened(theta), jax.jacfwd(objective.whitened)(theta)


@dataclass(frozen=True)
class NoiseFit:
    """The noise model a fit estimated from its residuals.

    Attributes:
        noise: the model with its scales (``view_scale``, ``touch_scale`` and, where told
            apart, ``depth_scale``) estimated.
        view_redundancy, touch_redundancy: the degrees of freedom behind each scale (the
            group's residuals less its share of the fitted parameters); a scale with fewer
            than :data:`MIN_REDUNDANCY` keeps its previous value.
        chi2: the sum of squares of the whitened residuals under ``noise``.
        depth_redundancy: the depth's share of ``view_redundancy`` (the rest is the
            image's); at least :data:`MIN_REDUNDANCY` for a ``depth_scale`` of its own.
    """

    noise: NoiseModel
    view_redundancy: float
    touch_redundancy: float
    chi2: float
    depth_redundancy: float | None = spec(omit="none", default=None)

    @property
    def dof(self) -> float:
        """The fit's degrees of freedom: the two groups' redundancies."""
        return self.view_redundancy + self.touch_redundancy


def _components(objective: NoiseObjective, J: np.ndarray, fit: NoiseFit):
    """Each noise component whose scale ``fit`` estimated: its part of ``JᵀJ`` (``J``'s rows
    whitened, views then touches) and the redundancy behind its scale."""
    n, k = np.asarray(objective.touch_whitener).shape
    Jv, Jt = J[: n * k].reshape(n, k, -1), J[n * k :]
    if k == 3 and fit.depth_redundancy is not None:
        G = np.asarray(objective.image_share)
        red_d = fit.depth_redundancy
        views = [(np.einsum("nad,nab,nbe->de", Jv, G, Jv), fit.view_redundancy - red_d),
                 (np.einsum("nad,nab,nbe->de", Jv, np.eye(k) - G, Jv), red_d)]  # fmt: skip
    else:
        views = [(np.einsum("nad,nae->de", Jv, Jv), fit.view_redundancy)]
    parts = [*views, (Jt.T @ Jt, fit.touch_redundancy)]
    # A scale with too little redundancy kept its stated value: nothing of it was estimated.
    return [(M, red) for M, red in parts if red >= MIN_REDUNDANCY]


@in_float64
def std_dof(
    objective: NoiseObjective,
    theta: Float[Array, " d"],
    fit: NoiseFit,
    prior_precision: np.ndarray | None = None,
    directions: np.ndarray | None = None,
) -> np.ndarray:
    """The degrees of freedom of each σ (Satterthwaite's): its 95 % interval is ± t·σ, t the
    97.5 % quantile of Student's t with that many.

    A σ rests on the noise scales the residuals estimated, each from its own redundancy
    (:class:`NoiseFit`): a variance ``Σ_k w_k·σ²`` that is a share ``w_k`` of component ``k``
    (the touches; the pictures, or with the hand's heights their image and their depth) is
    uncertain by ``Σ_k w_k²·2/ν_k``, as a χ² with ``1 / Σ_k (w_k²/ν_k)`` degrees of freedom.
    A parameter the touches alone set has the touches' (23 on a three-capture twin of nine
    landmarks), not the fit's (94): its interval is 4 % wider. The share of a component is
    ``cᵀ C M_k C c / cᵀ C JᵀJ C c`` for a direction ``c``, ``C = (JᵀJ + P)⁺`` and ``M_k``
    the component's part of ``JᵀJ``; a prior's information has no uncertainty of its own.

    Args:
        objective: the stage's :class:`NoiseObjective` at ``fit``'s scales.
        theta: its optimum.
        fit: the scales the residuals gave, with their redundancies (:func:`estimate_noise`).
        prior_precision: a prior's information on the free parameters, or ``None``.
        directions: ``(m, d)`` combinations of the free parameters (default: each parameter).

    Returns:
        ``(m,)`` degrees of freedom (``inf`` where no estimated scale enters).
    """
    J = np.asarray(whitened_jacobian(objective, jnp.asarray(theta))[1])
    C = _hat_inner(J, prior_precision)
    c = np.eye(J.shape[1]) if directions is None else np.atleast_2d(np.asarray(directions, float))
    CC = c @ C
    parts = [(np.einsum("md,de,me->m", CC, M, CC), red)
             for M, red in _components(objective, J, fit)]  # fmt: skip
    total = np.einsum("md,de,me->m", CC, J.T @ J, CC)
    inverse = sum(((v / np.where(total > 0, total, 1.0)) ** 2 / red for v, red in parts),
                  np.zeros(len(c)))  # fmt: skip
    with np.errstate(divide="ignore"):
        return np.where(inverse > 0, 1.0 / inverse, np.inf)


def _hat_inner(J: np.ndarray, prior_precision: np.ndarray | None) -> np.ndarray:
    """``(JᵀJ + P)⁺``, the hat matrix's middle."""
    A = J.T @ J
    if prior_precision is not None:
        A = A + prior_precision
    return np.linalg.pinv(A, hermitian=True)


def _apart(objective: NoiseObjective, H_rows, rv, view_count, ss_v: float, red_v: float):
    """The image's and the depth's variance factors of views with a z, ``(image, depth, the
    depth's sum of squares, its redundancy)``; ``None`` if either share of the redundancy is
    under :data:`MIN_REDUNDANCY` (then one scale serves both).

    Each row's whitened covariance is the identity, the image's part ``G_i`` and the depth's
    ``I − G_i``; a part's factor is its quadratic form over its share of the redundancy. Only
    views with a z see the depth directly: in x-y alone its share is a sideways lever on the
    image's, and the two estimates trade off (on the paper's single capture they did not
    settle in five rounds). ``H_rows``: each row's block of the hat matrix, ``(n, 3, 3)``.
    """
    G = np.eye(rv.shape[1]) - np.asarray(objective.image_share)
    red_d = float(np.einsum("nii->", G / view_count[:, None, None])
                  - np.einsum("nij,nji->", G, H_rows))  # fmt: skip
    u = np.asarray(objective.view_whitener)[:, :, 2]  # the profiled z offset's direction
    red_d -= float(np.einsum("ni,nij,nj->", u, G, u) / np.sum(u * u))
    red_i = red_v - red_d
    if red_d < MIN_REDUNDANCY or red_i < MIN_REDUNDANCY:
        return None
    ss_d = float(np.einsum("ni,nij,nj->", rv, G, rv))
    return (ss_v - ss_d) / red_i, ss_d / red_d, ss_d, red_d


@in_float64
def estimate_noise(
    objective: NoiseObjective,
    theta: Float[Array, " d"],
    noise: NoiseModel,
    prior_precision: np.ndarray | None = None,
    counts: tuple[np.ndarray, np.ndarray] | None = None,
) -> NoiseFit:
    """The scales of ``noise`` that the residuals of ``objective`` at its optimum ``theta``
    give: for each group (pictures, touches), its whitened sum of squares over its redundancy
    (the group's independent residuals less the trace of its part of the hat matrix):
    restricted maximum likelihood, one step from the scales ``objective`` was built with.

    The pictures' image and depth noise get a scale each where the depth's share of the
    redundancy is at least :data:`MIN_REDUNDANCY` (variance components: each component's
    quadratic form ``rᵀG r`` over its share ``tr(G(C − H))`` of the redundancy, ``G`` its
    part of the whitened covariance, ``C`` the rows' weights and ``H`` the hat matrix; the two
    shares add up to the group's). Otherwise one scale serves both, as stated.

    Args:
        objective: the stage's :class:`NoiseObjective`, built with ``noise``.
        theta: its optimum.
        noise: the model it was built with.
        prior_precision: a prior's information on the free parameters (its directions are
            not the data's to fit), or ``None``.
        counts: the rows' ``(view_count, touch_count)`` (:func:`row_counts`; default: ones).
    """
    r, J = (np.asarray(a) for a in whitened_jacobian(objective, jnp.asarray(theta)))
    n, k = np.asarray(objective.touch_whitener).shape
    view_count, touch_count = counts if counts is not None else (np.ones(n), np.ones(n))
    active_t = np.asarray(objective.touch_whitener) != 0
    size_v = float(np.sum(k / view_count))
    size_t = float(np.sum(active_t / touch_count[:, None]))
    inner = _hat_inner(J, prior_precision)
    h = np.einsum("ij,jk,ik->i", J, inner, J)  # the hat matrix's diagonal
    nv = n * k
    red_v, red_t = size_v - float(h[:nv].sum()), size_t - float(h[nv:].sum())
    ss_v, ss_t = float(np.sum(r[:nv] ** 2)), float(np.sum(r[nv:] ** 2))
    if k < 3:  # x-y only: one scale for the image and the depth (see _apart)
        fv = ss_v / red_v if red_v >= MIN_REDUNDANCY else 1.0
        ft = ss_t / red_t if red_t >= MIN_REDUNDANCY else 1.0
    else:
        # The views' and the touches' profiled z offsets are fitted parameters too.
        red_v, red_t = red_v - 1.0, red_t - float(np.any(active_t[:, 2]))
        ft = ss_t / red_t if red_t >= MIN_REDUNDANCY else 1.0
        Jv = J[:nv].reshape(n, k, -1)
        H_rows = np.einsum("nad,de,nbe->nab", Jv, inner, Jv)
        apart = _apart(objective, H_rows, r[:nv].reshape(n, k), view_count, ss_v, red_v)
        if apart is not None:
            fi, fd, ss_d, red_d = apart
            new = noise.scaled(fi, ft, depth=fd)
            chi2 = ((ss_v - ss_d) / max(fi, MIN_SCALE) + ss_d / max(fd, MIN_SCALE)
                    + ss_t / max(ft, MIN_SCALE))  # fmt: skip
            return NoiseFit(new, max(red_v, 0.0), max(red_t, 0.0), chi2, red_d)
        fv = ss_v / red_v if red_v >= MIN_REDUNDANCY else 1.0
    new = noise.scaled(fv, ft)
    chi2 = ss_v / max(fv, MIN_SCALE) + ss_t / max(ft, MIN_SCALE)
    return NoiseFit(new, max(red_v, 0.0), max(red_t, 0.0), chi2)
