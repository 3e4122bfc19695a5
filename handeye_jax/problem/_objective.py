"""The fitness functions F1st (eqs. 17–20) and F2nd (eqs. 21–25) as named blocks of residuals.

An objective maps the flat vector ``theta`` of a fit's free parameters to named *blocks*:
``f1`` (image chain against tablet chain) and ``f2`` (hand positions) for both stages, and
``prior`` when a Gaussian prior is given. Its value (what DE minimises, mm) is the sum of the
blocks' values, and its least-squares residuals (what Levenberg–Marquardt minimises the squares
of) are theirs stacked: both are defined once, on :class:`AbstractObjective`, from
:meth:`~AbstractObjective.blocks`. The robust loss with the leave-one-out weights
(:class:`LossObjective`) and the prior (:class:`PriorObjective`) are wrappers that change or
add blocks.

The model enters as a *template* and the names of its free parameters: ``theta`` is put into
the template (:func:`~handeye_jax.put`); every other parameter keeps the template's value.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import math
import operator
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..data import Observations
from ..models import AbstractCorrection, AbstractModel, AbstractParametric
from ._losses import AbstractLoss
from ._params import put

# Smoothing of |e| for the least-squares form of a length block, mm. Below it the polish sees a
# quadratic, so noise-free data still converges quadratically to zero; above it, the sum of
# squared residuals equals the block's value to within this many mm per landmark.
NORM_SMOOTHING_MM = 1e-9

#: Up to this many error vectors, a block's mean length is written as a sum of single terms.
UNROLL_LANDMARKS = 64


class ChainPoints(eqx.Module):
    """The four point sets the objectives compare, in the base frame, x-y only, mm.

    Attributes:
        image_xy: landmarks through the image chain, ``x_bi`` of eq. (5).
        tablet_xy: landmarks through the tablet chain, ``x_bt`` of eq. (10).
        pen_offset_xy: the pen offset ``x'`` at each touch, eqs. (6)–(7).
        hand_target_xy: the touch-compensated hand positions ``x_r'`` of eq. (20).
        image_z, tablet_z, touched_z: where touches carry the hand's height, the z of each
            row's view (the camera at ``z_c = 0`` on the hand), of its landmark through the
            tablet chain (the tablet at ``z_t = 0``) and of the touched point relative to its
            landmark, mm; else ``None``.
        hand_z: the hand's height at each row's touch, mm (NaN where not recorded), or None.
    """

    image_xy: Float[Array, "n 2"]
    tablet_xy: Float[Array, "n 2"]
    pen_offset_xy: Float[Array, "n 2"]
    hand_target_xy: Float[Array, "n 2"]
    image_z: Float[Array, " n"] | None = None
    tablet_z: Float[Array, " n"] | None = None
    touched_z: Float[Array, " n"] | None = None
    hand_z: Float[Array, " n"] | None = None


def chain_points(model: AbstractModel, obs: Observations) -> ChainPoints:
    """Evaluate the model's transform chain on one calibration's observations."""
    x_bi = model.image_to_base(
        obs.image_px, obs.depth_mm, obs.rig, obs.capture_position_mm, obs.capture_phi_deg()
    )
    x_bt = model.tablet_to_base(obs.tablet_mm)
    x_off = model.pen_offset(obs.phi_deg())
    touch_base = model.tablet_vector_to_base(obs.touch_error_mm)
    z = {}
    if obs.hand_z_mm is not None:
        z = dict(image_z=x_bi[:, 2], tablet_z=x_bt[:, 2], touched_z=touch_base[:, 2],
                 hand_z=obs.hand_z_mm)  # fmt: skip
    return ChainPoints(
        image_xy=x_bi[:, :2],
        tablet_xy=x_bt[:, :2],
        pen_offset_xy=x_off[:, :2],
        hand_target_xy=obs.hand_xy_mm - touch_base[:, :2],
        **z,
    )


class HeightOffsets(eqx.Module):
    """The vertical terms the data determine, mm: sums and differences of the heights
    ``z_c`` (camera on the hand, along its z), ``z_t`` (tablet in the base) and ``z_p`` (pen
    tip on the hand) that no x-y term sees.

    Attributes:
        tablet_plus_camera_mm: ``z_t + z_c``, from the views' depths at their capture heights.
        tablet_plus_pen_mm: ``z_t + z_p``, from the hand's heights at the touches.
        pen_minus_camera_mm: ``z_p − z_c``: what commanding a height needs (a point seen at
            height ``z`` with the camera taken at ``z_c = 0`` is touched with the hand at
            ``z + z_p − z_c``).
    """

    tablet_plus_camera_mm: Float[Array, ""]
    tablet_plus_pen_mm: Float[Array, ""]

    @property
    def pen_minus_camera_mm(self) -> Float[Array, ""]:
        return self.tablet_plus_pen_mm - self.tablet_plus_camera_mm


@dataclass(frozen=True)
class Heights:
    """What the hand's heights at the touches determined, mm: ``z_p − z_c`` (what a height
    command needs) and its standard error from the z scatter, ``z_t + z_c`` and ``z_t + z_p``,
    the mean |z error| of the views and of the touches, and the rows behind each."""

    strict: ClassVar[bool] = True

    pen_minus_camera_mm: float
    tablet_plus_camera_mm: float
    tablet_plus_pen_mm: float
    pen_minus_camera_sigma_mm: float
    f1z_mm: float
    f2z_mm: float
    n_views: int
    n_touches: int


def height_summary(model: AbstractModel, obs: Observations) -> Heights | None:
    """What the hand's heights at the touches determine, for a result (``None`` without)."""
    if obs.hand_z_mm is None:
        return None
    points = chain_points(model, obs)
    h = height_offsets(points)
    e = stage1_errors(points)
    ok = np.isfinite(np.asarray(obs.hand_z_mm))
    r1 = np.asarray(e.image_vs_tablet_z)
    r2 = np.asarray(points.hand_z - points.tablet_z - points.touched_z)[ok]
    r2 = r2 - r2.mean()
    n1, n2 = r1.size, int(ok.sum())
    sigma = math.sqrt(float(np.mean(r1**2)) / n1 + float(np.mean(r2**2)) / n2)
    return Heights(
        pen_minus_camera_mm=float(h.pen_minus_camera_mm),
        tablet_plus_camera_mm=float(h.tablet_plus_camera_mm),
        tablet_plus_pen_mm=float(h.tablet_plus_pen_mm), pen_minus_camera_sigma_mm=sigma,
        f1z_mm=float(np.mean(np.abs(r1))), f2z_mm=float(np.mean(np.abs(r2))),
        n_views=n1, n_touches=n2,
    )  # fmt: skip


def _finite_mean(x: Float[Array, " n"]) -> Float[Array, ""]:
    ok = jnp.isfinite(x)
    return jnp.sum(jnp.where(ok, x, 0.0)) / jnp.sum(ok)


def height_offsets(points: ChainPoints) -> HeightOffsets:
    """The determined vertical terms at a stage-1 model's chain points (``points`` with
    heights): each the mean over the rows that carry it, the least-squares value given the
    rest of the model."""
    return HeightOffsets(
        tablet_plus_camera_mm=jnp.mean(points.image_z - points.tablet_z),
        tablet_plus_pen_mm=_finite_mean(points.hand_z - points.tablet_z - points.touched_z),
    )


class StageErrors(eqx.Module):
    """A stage's per-landmark error vectors, mm: eqs. (18)–(19) or (22)–(23)."""

    image_vs_tablet: Float[Array, "n 2"]
    hand: Float[Array, "n 2"]
    image_vs_tablet_z: Float[Array, " n"] | None = None
    hand_z: Float[Array, " n"] | None = None


def stage1_errors(points: ChainPoints) -> StageErrors:
    """Eqs. (18)–(19): ``x_bi − x_bt`` and ``(x_bi − x') − x_r'``.

    With the hand's heights, also the z errors of the views against the tablet chain and of
    the touches, each less its mean (:func:`height_offsets`: the determined vertical terms
    are profiled out, so the model needs no z parameter); a touch without a height gives 0.
    """
    errors = StageErrors(
        image_vs_tablet=points.image_xy - points.tablet_xy,
        hand=points.image_xy - points.pen_offset_xy - points.hand_target_xy,
    )
    if points.hand_z is None:
        return errors
    h = height_offsets(points)
    e1 = points.image_z - points.tablet_z - h.tablet_plus_camera_mm
    e2 = points.hand_z - points.tablet_z - points.touched_z - h.tablet_plus_pen_mm
    ok = jnp.isfinite(e2)
    # Scaled so the block's mean over all rows is the mean over the rows with a height.
    e2 = jnp.where(ok, e2, 0.0) * (ok.shape[0] / jnp.sum(ok))
    return dataclasses.replace(errors, image_vs_tablet_z=e1, hand_z=e2)


def _as_vectors(e: Float[Array, " n"]) -> Float[Array, "n 2"]:
    # 1-D errors as 2-D vectors with a zero y: their lengths are |e|.
    return jnp.stack([e, jnp.zeros_like(e)], axis=-1)


def stage2_errors(
    correction: AbstractCorrection, points: ChainPoints, centre_index: int
) -> tuple[StageErrors, Float[Array, "2 2"]]:
    """Eqs. (22)–(23) with A2 acting on A1's output, as eq. (25) deploys it (notes, item 5).

    Returns the errors and the two centres of rotation (rows: A1's, A2's), mm. Each centre is
    landmark ``centre_index`` of the points that map turns.
    """
    centre1 = points.image_xy[centre_index]
    a1 = correction.first(points.image_xy, centre1)
    hand_cmd = a1 - points.pen_offset_xy
    centre2 = hand_cmd[centre_index]
    a2 = correction.second(hand_cmd, centre2)
    errors = StageErrors(image_vs_tablet=a1 - points.tablet_xy, hand=a2 - points.hand_target_xy)
    return errors, jnp.stack([centre1, centre2])


def _length(e: Float[Array, "n 2"]) -> Float[Array, " n"]:
    return jnp.sqrt(e[:, 0] ** 2 + e[:, 1] ** 2)


def _smoothed_length(e: Float[Array, "n k"]) -> Float[Array, " n"]:
    return jnp.sqrt(jnp.sum(e**2, axis=-1) + NORM_SMOOTHING_MM**2)


def _mean(x: Float[Array, " n"]) -> Float[Array, ""]:
    # Under vmap over a population, a reduction inside a fused loop runs as a scalar inner loop;
    # a sum of n separate terms fuses into one elementwise, vectorised loop over the members
    # instead (benchmarks/RESULTS.md, "the unrolled mean").
    n = x.shape[0]
    if n > UNROLL_LANDMARKS:
        return jnp.mean(x)
    return sum(x[m] for m in range(n)) / n


def norms(errors: StageErrors) -> tuple[Float[Array, " n"], Float[Array, " n"]]:
    """Per-landmark Euclidean error lengths ``(|e1|, |e2|)``, mm."""
    return _length(errors.image_vs_tablet), _length(errors.hand)


def fitness(errors: StageErrors) -> tuple[Float[Array, ""], Float[Array, ""], Float[Array, ""]]:
    """``(F, f1, f2)``: the mean error lengths and their sum, eqs. (17) and (21), mm."""
    n1, n2 = norms(errors)
    f1, f2 = _mean(n1), _mean(n2)
    return f1 + f2, f1, f2


# -- blocks --------------------------------------------------------------------------------


class AbstractBlock(eqx.Module):
    """A named part of an objective: a value (mm) and residuals whose squares sum to it."""

    @abc.abstractmethod
    def value(self) -> Float[Array, ""]:
        """The block's contribution to the objective, mm."""

    @abc.abstractmethod
    def residuals(self) -> Float[Array, " r"]:
        """Residuals whose sum of squares is :meth:`value` (up to the length smoothing)."""


class LengthBlock(AbstractBlock):
    """Error vectors whose mean Euclidean length is the block's value: the paper's f1 or f2.

    Attributes:
        errors: one error vector per landmark, mm.
    """

    errors: Float[Array, "n 2"]

    def value(self):
        return _mean(_length(self.errors))

    def residuals(self):
        # Each error vector scaled by (|e|² + ε²)^(-1/4): a least-squares solver then minimises
        # the same mean of Euclidean lengths that DE does, not a sum of squares.
        e = self.errors
        n = e.shape[0]
        w = (jnp.sum(e**2, axis=-1, keepdims=True) + NORM_SMOOTHING_MM**2) ** -0.25
        return (e * w / jnp.sqrt(n)).reshape(-1)


class WeightedLengthBlock(AbstractBlock):
    """``Σ w·ρ(|e|) / Σ w`` over the error vectors: a loss ρ and a weight per landmark.

    With ``ρ(r) = r`` and unit weights this is :class:`LengthBlock`'s value.
    """

    errors: Float[Array, "n 2"]
    weights: Float[Array, " n"]
    loss: AbstractLoss

    def terms(self) -> Float[Array, " n"]:
        """Each landmark's share of the (smoothed) value, mm; twice differentiable."""
        w = self.weights / jnp.sum(self.weights)
        return w * self.loss(_smoothed_length(self.errors))

    def value(self):
        w = self.weights / jnp.sum(self.weights)
        return jnp.sum(w * self.loss(jnp.linalg.norm(self.errors, axis=-1)))

    def residuals(self):
        w = self.weights / jnp.sum(self.weights)
        r = _smoothed_length(self.errors)
        # sqrt(w) apart: a zero weight must give a zero gradient, not 0·∞.
        scale = jnp.sqrt(w) * jnp.sqrt(self.loss(r)) / r
        return (self.errors * scale[:, None]).reshape(-1)


class SquaresBlock(AbstractBlock):
    """Residuals whose plain sum of squares is the block's value (a prior's)."""

    r: Float[Array, " k"]

    def value(self):
        return jnp.sum(self.r**2)

    def residuals(self):
        return self.r


class GaussianBlock(AbstractBlock):
    """``Σ w·c·|e|² / Σ w`` over the error vectors: Gaussian errors' negative log-likelihood.

    With ``c = s/(2σ²)`` and unit weights, ``s/n`` times the negative log-likelihood (less its
    constant) of ``n`` error vectors whose components are normal with σ: the data term of a
    MAP fit whose prior was built as ``JᵀJ/σ²`` (see :class:`GaussianObjective`).

    Attributes:
        errors: one error vector per landmark, mm.
        scale: ``c``, 1/mm.
        weights: one non-negative weight per landmark (1 = use, 0 = leave out).
    """

    errors: Float[Array, "n 2"]
    scale: Float[Array, ""]
    weights: Float[Array, " n"]

    def terms(self) -> Float[Array, " n"]:
        """Each landmark's share of the value, mm."""
        w = self.weights / jnp.sum(self.weights)
        return w * self.scale * jnp.sum(self.errors**2, axis=-1)

    def value(self):
        return jnp.sum(self.terms())

    def residuals(self):
        w = self.weights / jnp.sum(self.weights)
        return (self.errors * jnp.sqrt(self.scale * w)[:, None]).reshape(-1)


# -- objectives ----------------------------------------------------------------------------


class AbstractObjective(eqx.Module):
    """An objective: named blocks as a function of the free parameters ``theta``.

    Final subclasses implement :meth:`blocks` and :meth:`on_landmarks` and nothing else; the
    value, the residuals and the terms are defined here once, from the blocks.
    """

    @abc.abstractmethod
    def blocks(self, theta: Float[Array, " d"]) -> dict[str, AbstractBlock]:
        """The objective's blocks at ``theta``, by name (``f1``, ``f2``, ``prior``…)."""

    @abc.abstractmethod
    def on_landmarks(self, idx: Int[np.ndarray, " m"]) -> AbstractObjective:
        """The same objective on landmarks ``idx`` (sorted indices) alone: a cheaper stand-in
        for a search over many landmarks."""

    def __call__(self, theta: Float[Array, " d"]) -> Float[Array, ""]:
        return functools.reduce(operator.add, (b.value() for b in self.blocks(theta).values()))

    def residuals(self, theta: Float[Array, " d"]) -> Float[Array, " r"]:
        return jnp.concatenate([b.residuals() for b in self.blocks(theta).values()])

    def terms(self, theta: Float[Array, " d"]) -> dict[str, Float[Array, ""]]:
        """Each block's value at ``theta``, mm."""
        return {k: b.value() for k, b in self.blocks(theta).items()}


def _template(
    template: AbstractParametric | type[AbstractParametric],
) -> AbstractParametric:
    """A template given as a class stands for every parameter free: any values do."""
    if isinstance(template, type):
        return template.nominal()
    return template


def _free(template: AbstractParametric, free: Sequence[str] | None) -> tuple[str, ...]:
    names = type(template).param_names
    if free is None:
        return names
    free = tuple(free)
    unknown = [n for n in free if n not in names]
    if unknown:
        raise ValueError(f"unknown parameter {unknown[0]!r}; known: {', '.join(names)}")
    return free


class Stage1Objective(AbstractObjective):
    """F1st (eq. 17): blocks ``f1`` (eq. 18) and ``f2`` (eq. 19); with the hand's heights at
    the touches also ``f1z`` and ``f2z``, the mean |z error| of the views and of the touches
    (see :func:`stage1_errors`).

    Attributes:
        template: the model; parameters not in ``free`` keep its values.
        obs: the observations.
        free: the names of the parameters ``theta`` holds, in order (default: all of the
            model's, in its ``param_names`` order).
    """

    template: AbstractModel
    obs: Observations
    free: tuple[str, ...] = eqx.field(static=True)

    def __init__(
        self,
        template: AbstractModel | type[AbstractModel],
        obs: Observations,
        free: Sequence[str] | None = None,
    ):
        self.template = _template(template)
        self.obs = obs
        self.free = _free(self.template, free)

    def model(self, theta: Float[Array, " d"]) -> AbstractModel:
        """The template with ``theta`` put in."""
        return put(self.template, self.free, theta)

    def blocks(self, theta):
        e = _stage1_errors(self.template, self.free, self.obs, theta)
        out = {"f1": LengthBlock(e.image_vs_tablet), "f2": LengthBlock(e.hand)}
        if e.hand_z is not None:  # the hand's heights were recorded: the z blocks
            out["f1z"] = LengthBlock(_as_vectors(e.image_vs_tablet_z))
            out["f2z"] = LengthBlock(_as_vectors(e.hand_z))
        return out

    def on_landmarks(self, idx):
        return Stage1Objective(self.template, landmark_subset(self.obs, idx), self.free)


class Stage2Objective(AbstractObjective):
    """F2nd (eq. 21): blocks ``f1`` (eq. 22) and ``f2`` (eq. 23) of a correction, the stage-1
    model held fixed (its chain's points are given).

    Attributes:
        template: the correction; parameters not in ``free`` keep its values.
        points: the stage-1 model's chain points.
        centre_index: the landmark whose mapped points are the centres of rotation.
        free: the names of the parameters ``theta`` holds (default: all).
    """

    template: AbstractCorrection
    points: ChainPoints
    centre_index: int = eqx.field(static=True)
    free: tuple[str, ...] = eqx.field(static=True)

    def __init__(
        self,
        template: AbstractCorrection | type[AbstractCorrection],
        points: ChainPoints,
        centre_index: int,
        free: Sequence[str] | None = None,
    ):
        self.template = _template(template)
        self.points = points
        self.centre_index = int(centre_index)
        self.free = _free(self.template, free)

    def model(self, theta: Float[Array, " d"]) -> AbstractCorrection:
        """The template with ``theta`` put in."""
        return put(self.template, self.free, theta)

    def blocks(self, theta):
        e = _stage2_errors(self.template, self.free, self.points, self.centre_index, theta)
        return {"f1": LengthBlock(e.image_vs_tablet), "f2": LengthBlock(e.hand)}

    def on_landmarks(self, idx):
        """See :meth:`AbstractObjective.on_landmarks`; ``idx`` must hold the centre landmark."""
        idx = np.asarray(idx)
        if self.centre_index not in idx:
            raise ValueError(f"landmarks {idx} leave out the centre {self.centre_index}")
        points = jax.tree.map(lambda a: a[idx], self.points)
        centre = int(np.flatnonzero(idx == self.centre_index)[0])
        return Stage2Objective(self.template, points, centre, self.free)


# The stages' errors as nested jits: every program that evaluates or differentiates an
# objective (DE, LM, reports, diagnostics) then reuses one trace of the transform chain.
# XLA inlines the call, so the compiled loops are unchanged.
@functools.partial(jax.jit, static_argnums=1)
def _stage1_errors(template, free, obs: Observations, theta) -> StageErrors:
    return stage1_errors(chain_points(put(template, free, theta), obs))


@functools.partial(jax.jit, static_argnums=(1, 3))
def _stage2_errors(template, free, points: ChainPoints, centre_index: int, theta) -> StageErrors:
    return stage2_errors(put(template, free, theta), points, centre_index)[0]


class LossObjective(AbstractObjective):
    """Another objective with a loss ρ on each error length and a weight on each landmark.

    Every :class:`LengthBlock` of ``base`` becomes ``Σ w·ρ(|e|)/Σ w``: with ``l1`` and unit
    weights, the paper's F. A :class:`GaussianBlock` takes the weights (its own loss stays);
    other blocks (a prior's) pass through unchanged.

    Attributes:
        base: the objective whose length blocks are weighted.
        loss: ``ρ``.
        weights: one non-negative weight per landmark (1 = use, 0 = leave out).
    """

    base: AbstractObjective
    loss: AbstractLoss
    weights: Float[Array, " n"]

    def blocks(self, theta):
        out = {}
        for name, b in self.base.blocks(theta).items():
            if isinstance(b, LengthBlock):
                b = WeightedLengthBlock(b.errors, self.weights, self.loss)
            elif isinstance(b, GaussianBlock):  # a MAP fit's data term: weighted, no loss
                b = GaussianBlock(b.errors, b.scale, self.weights)
            out[name] = b
        return out

    def on_landmarks(self, idx):
        return LossObjective(self.base.on_landmarks(idx), self.loss, self.weights[idx])


class GaussianObjective(AbstractObjective):
    """Another objective with Gaussian errors in place of the paper's error lengths.

    Each :class:`LengthBlock` (mean ``|e|``) of ``base`` becomes a :class:`GaussianBlock` (mean
    ``c·|e|²``). A previous fit's posterior, the prior of a recalibration, is Gaussian with
    precision ``JᵀJ/σ²``; with ``c = s/(2σ²)`` the new data are weighed under the same noise
    model, so that neither the prior nor the data wins a conflict by the shape of its term
    (a mean length's pull is bounded, a Gaussian prior's is not).

    Attributes:
        base: the paper's objective.
        scale: ``c``, 1/mm.
    """

    base: AbstractObjective
    scale: Float[Array, ""]

    def blocks(self, theta):
        return {
            name: GaussianBlock(b.errors, self.scale, jnp.ones(b.errors.shape[0]))
            if isinstance(b, LengthBlock)
            else b
            for name, b in self.base.blocks(theta).items()
        }

    def on_landmarks(self, idx):
        return GaussianObjective(self.base.on_landmarks(idx), self.scale)


class PriorObjective(AbstractObjective):
    """Another objective plus a Gaussian prior's block ``prior``: the MAP objective.

    The data blocks are mean error lengths (mm): ``s/n`` times the negative log-likelihood of
    ``n`` landmarks' error vectors with density ``∝ exp(−|e|/s)``. The prior block's residuals
    are ``√(s/n)·W·(θ_P − μ)/√2`` with ``WᵀW = Σ⁻¹``, whose squares sum to ``s/n`` times the
    prior's negative log-density (less its constant). So the whole objective is ``s/n`` times
    the negative log-posterior, in mm, and its minimiser is the MAP estimate.

    Attributes:
        base: the data objective.
        index: the positions in ``theta`` of the prior's parameters.
        mean: the prior mean ``μ``, in the parameters' units.
        whitener: ``W``.
        weight: ``s/n``, mm: the data's error scale over the number of landmarks.
    """

    base: AbstractObjective
    index: tuple[int, ...] = eqx.field(static=True)
    mean: Float[Array, " k"]
    whitener: Float[Array, "k k"]
    weight: Float[Array, ""]

    def nll_residuals(self, theta: Float[Array, " d"]) -> Float[Array, " k"]:
        """``W·(θ_P − μ)/√2``: squares summing to the prior's negative log-density, less its
        constant ``(k/2)·log(2π) + ½·log det Σ``."""
        d = jnp.stack([theta[i] for i in self.index]) - self.mean
        return (self.whitener @ d) / math.sqrt(2.0)

    def blocks(self, theta):
        out = dict(self.base.blocks(theta))
        out["prior"] = SquaresBlock(jnp.sqrt(self.weight) * self.nll_residuals(theta))
        return out

    def on_landmarks(self, idx):
        return PriorObjective(
            self.base.on_landmarks(idx), self.index, self.mean, self.whitener, self.weight
        )


def data_objective(objective: AbstractObjective) -> AbstractObjective:
    """The paper's objective inside any wrappers (its blocks are the data's error vectors).

    A wrapper is an objective whose ``base`` is another (a loss, a prior, a noise model)."""
    while isinstance(getattr(objective, "base", None), AbstractObjective):
        objective = objective.base
    return objective


def errors_of(objective: AbstractObjective, theta: Float[Array, " d"]) -> StageErrors:
    """The data's error vectors of ``objective``'s stage at ``theta`` (the paper's measure,
    whatever loss or prior wraps it)."""
    blocks = data_objective(objective).blocks(theta)
    return StageErrors(image_vs_tablet=blocks["f1"].errors, hand=blocks["f2"].errors)


def landmark_terms(objective: LossObjective, theta: Float[Array, " d"]) -> Float[Array, " n"]:
    """Each landmark's share of a :class:`LossObjective`'s data blocks at ``theta``, mm
    (smoothed, so twice differentiable: for derivatives per landmark)."""
    blocks = objective.blocks(theta)
    return sum(b.terms() for b in blocks.values()
               if isinstance(b, WeightedLengthBlock | GaussianBlock))  # fmt: skip


# -- landmark subsets --------------------------------------------------------------------------

#: The per-landmark fields of :class:`Observations`.
_LANDMARK_FIELDS = (
    "image_px", "depth_mm", "tablet_mm", "hand_xy_mm", "hand_angle_deg", "touch_error_mm",
)  # fmt: skip


#: The optional per-row fields of data from several captures.
_ROW_FIELDS = (
    "capture_position_mm", "capture_hand_angle_deg", "hand_z_mm", "capture_index", "touch_index",
)  # fmt: skip


def spread_landmarks(n: int, k: int, include: int | None = None) -> Int[np.ndarray, " m"]:
    """Up to ``k`` landmark indices spread evenly over ``0 … n−1`` (touch order), sorted, plus
    ``include`` (e.g. the centre of rotation); all ``n`` when ``n <= k``."""
    idx = np.arange(n) if n <= k else np.round(np.linspace(0, n - 1, k)).astype(int)
    if include is not None:
        idx = np.union1d(idx, [include])
    return np.unique(idx)


def landmark_subset(obs: Observations, idx: Int[np.ndarray, " m"]) -> Observations:
    """The observations of landmarks ``idx`` (sorted) alone; the centre of rotation becomes
    the nearest of them to the old one's index if it is not among them."""
    idx = np.asarray(idx)
    fields = _LANDMARK_FIELDS + tuple(f for f in _ROW_FIELDS if getattr(obs, f) is not None)
    pick = {f: getattr(obs, f)[idx] for f in fields}
    centre = int(np.argmin(np.abs(idx - obs.centre_index)))
    return dataclasses.replace(obs, **pick, centre_index=centre)
