"""The fitness functions F1st (eqs. 17–20) and F2nd (eqs. 21–25), written once for any model.

Both compare four point sets in the base frame's x-y plane (section 3.5), computed by
:func:`chain_points`. Each objective is an equinox Module mapping a flat parameter vector to a
scalar, so it is a pytree the optimisers can ``jit`` and ``vmap`` without knowing what it is.
"""

from __future__ import annotations

import abc
import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .models import AbstractCorrection, AbstractModel
from .observations import Observations

# Smoothing of |e| for the least-squares form of the objective, mm. Below it the polish sees a
# quadratic, so noise-free data still converges quadratically to zero; above it, the sum of
# squared residuals equals F to within this many mm per landmark.
NORM_SMOOTHING_MM = 1e-9


class ChainPoints(eqx.Module):
    """The four point sets the objectives compare, in the base frame, x-y only, mm.

    Attributes:
        image_xy: landmarks through the image chain, ``x_bi`` of eq. (5).
        tablet_xy: landmarks through the tablet chain, ``x_bt`` of eq. (10).
        pen_offset_xy: the pen offset ``x'`` at each touch, eqs. (6)–(7).
        hand_target_xy: the touch-compensated hand positions ``x_r'`` of eq. (20).
    """

    image_xy: Float[Array, "n 2"]
    tablet_xy: Float[Array, "n 2"]
    pen_offset_xy: Float[Array, "n 2"]
    hand_target_xy: Float[Array, "n 2"]


def chain_points(model: AbstractModel, obs: Observations) -> ChainPoints:
    """Evaluate the model's transform chain on one calibration's observations."""
    x_bi = model.image_to_base(obs.image_px, obs.depth_mm, obs.rig)
    x_bt = model.tablet_to_base(obs.tablet_mm)
    x_off = model.pen_offset(obs.phi_deg())
    touch_base = model.tablet_vector_to_base(obs.touch_error_mm)
    return ChainPoints(
        image_xy=x_bi[:, :2],
        tablet_xy=x_bt[:, :2],
        pen_offset_xy=x_off[:, :2],
        hand_target_xy=obs.hand_xy_mm - touch_base[:, :2],
    )


#: The per-landmark fields of :class:`Observations`.
_LANDMARK_FIELDS = (
    "image_px", "depth_mm", "tablet_mm", "hand_xy_mm", "hand_angle_deg", "touch_error_mm",
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
    pick = {f: getattr(obs, f)[idx] for f in _LANDMARK_FIELDS}
    centre = int(np.argmin(np.abs(idx - obs.centre_index)))
    return dataclasses.replace(obs, **pick, centre_index=centre)


class Errors(eqx.Module):
    """Per-landmark error vectors of one stage, mm: ``f1`` and ``f2`` are their mean norms."""

    image_vs_tablet: Float[Array, "n 2"]
    hand: Float[Array, "n 2"]


def stage1_errors(points: ChainPoints) -> Errors:
    """Eqs. (18)–(19): ``x_bi − x_bt`` and ``(x_bi − x') − x_r'``."""
    return Errors(
        image_vs_tablet=points.image_xy - points.tablet_xy,
        hand=points.image_xy - points.pen_offset_xy - points.hand_target_xy,
    )


def stage2_errors(
    correction: AbstractCorrection, points: ChainPoints, centre_index: int
) -> tuple[Errors, Float[Array, "2 2"]]:
    """Eqs. (22)–(23) with A2 acting on A1's output, as eq. (25) deploys it (notes, item 5).

    Returns the errors and the two centres of rotation (rows: A1's, A2's), mm. Each centre is
    landmark ``centre_index`` of the points that map turns.
    """
    centre1 = points.image_xy[centre_index]
    a1 = correction.first(points.image_xy, centre1)
    hand_cmd = a1 - points.pen_offset_xy
    centre2 = hand_cmd[centre_index]
    a2 = correction.second(hand_cmd, centre2)
    errors = Errors(image_vs_tablet=a1 - points.tablet_xy, hand=a2 - points.hand_target_xy)
    return errors, jnp.stack([centre1, centre2])


#: Up to this many landmarks, a stage's mean error length is written as a sum of single terms.
UNROLL_LANDMARKS = 64


def _length(e: Float[Array, "n 2"]) -> Float[Array, " n"]:
    return jnp.sqrt(e[:, 0] ** 2 + e[:, 1] ** 2)


def _mean(x: Float[Array, " n"]) -> Float[Array, ""]:
    # Under vmap over a population, a reduction inside a fused loop runs as a scalar inner loop;
    # a sum of n separate terms fuses into one elementwise, vectorised loop over the members
    # instead (one DE generation at N = 10,000 about 9 % faster, benchmarks/de_throughput.py).
    n = x.shape[0]
    if n > UNROLL_LANDMARKS:
        return jnp.mean(x)
    return sum(x[m] for m in range(n)) / n


def norms(errors: Errors) -> tuple[Float[Array, " n"], Float[Array, " n"]]:
    """Per-landmark Euclidean error lengths ``(|e1|, |e2|)``, mm."""
    return _length(errors.image_vs_tablet), _length(errors.hand)


def fitness(errors: Errors) -> tuple[Float[Array, ""], Float[Array, ""], Float[Array, ""]]:
    """``(F, f1, f2)``: the mean error lengths and their sum, eqs. (17) and (21), mm."""
    n1, n2 = norms(errors)
    f1, f2 = _mean(n1), _mean(n2)
    return f1 + f2, f1, f2


def sqrt_residuals(errors: Errors) -> Float[Array, " 4n"]:
    """Residuals whose sum of squares is F: each error vector scaled by ``(|e|² + ε²)^(-1/4)``.

    This is how a least-squares solver (Levenberg–Marquardt) minimises the same mean of
    Euclidean lengths that DE does, rather than a sum of squares.
    """

    def scaled(e):
        n = e.shape[0]
        w = (jnp.sum(e**2, axis=-1, keepdims=True) + NORM_SMOOTHING_MM**2) ** -0.25
        return (e * w / jnp.sqrt(n)).reshape(-1)

    return jnp.concatenate([scaled(errors.image_vs_tablet), scaled(errors.hand)])


class AbstractObjective(eqx.Module):
    """A stage's fitness as a function of a flat parameter vector ``theta``.

    Calling it gives F (mm); :meth:`residuals` gives the least-squares form of the same F.
    """

    @abc.abstractmethod
    def errors(self, theta: Float[Array, " d"]) -> Errors:
        """The per-landmark error vectors at ``theta``."""

    def __call__(self, theta: Float[Array, " d"]) -> Float[Array, ""]:
        return fitness(self.errors(theta))[0]

    def residuals(self, theta: Float[Array, " d"]) -> Float[Array, " r"]:
        return sqrt_residuals(self.errors(theta))

    def on_landmarks(self, idx: Int[np.ndarray, " m"]) -> AbstractObjective:
        """The same objective on landmarks ``idx`` (sorted indices) alone: a cheaper stand-in
        for a search over many landmarks."""
        raise NotImplementedError(f"{type(self).__name__} cannot select landmarks")


class Stage1Objective(AbstractObjective):
    """F1st as a function of a model's flat parameter vector."""

    model_cls: type[AbstractModel] = eqx.field(static=True)
    obs: Observations

    def errors(self, theta: Float[Array, " d"]) -> Errors:
        return _stage1_errors(self.model_cls, self.obs, theta)

    def on_landmarks(self, idx: Int[np.ndarray, " m"]) -> Stage1Objective:
        return Stage1Objective(self.model_cls, landmark_subset(self.obs, idx))


class Stage2Objective(AbstractObjective):
    """F2nd as a function of a correction's flat parameter vector, the model held fixed."""

    correction_cls: type[AbstractCorrection] = eqx.field(static=True)
    points: ChainPoints
    centre_index: int = eqx.field(static=True)

    def errors(self, theta: Float[Array, " d"]) -> Errors:
        return _stage2_errors(self.correction_cls, self.points, self.centre_index, theta)

    def on_landmarks(self, idx: Int[np.ndarray, " m"]) -> Stage2Objective:
        """See :meth:`AbstractObjective.on_landmarks`; ``idx`` must hold the centre landmark."""
        idx = np.asarray(idx)
        if self.centre_index not in idx:
            raise ValueError(f"landmarks {idx} leave out the centre {self.centre_index}")
        points = jax.tree.map(lambda a: a[idx], self.points)
        centre = int(np.flatnonzero(idx == self.centre_index)[0])
        return Stage2Objective(self.correction_cls, points, centre)


# The stages' errors as nested jits: every program that evaluates or differentiates an
# objective (DE, LM, reports, diagnostics) then reuses one trace of the transform chain
# instead of tracing it again, about 0.3 s less tracing in a first calibration. XLA inlines
# the call, so the compiled loops are unchanged (bit-identical DE populations, measured).
@functools.partial(jax.jit, static_argnums=0)
def _stage1_errors(model_cls, obs: Observations, theta) -> Errors:
    return stage1_errors(chain_points(model_cls.from_vector(theta), obs))


@functools.partial(jax.jit, static_argnums=(0, 2))
def _stage2_errors(correction_cls, points: ChainPoints, centre_index: int, theta) -> Errors:
    return stage2_errors(correction_cls.from_vector(theta), points, centre_index)[0]
