"""Per-landmark losses and weights on top of a stage's objective: the robust option and LOO.

The paper's F is the mean Euclidean error length of each term. A loss ``ρ`` replaces the
length ``r`` of each error vector by ``ρ(r)`` (mm), so one bad touch pulls the fit less:

* ``l1``: ``ρ(r) = r``, the paper's F (the default);
* ``huber``: ``r²/(2c)`` below the scale ``c``, ``r − c/2`` above it;
* ``cauchy``: ``(c/2)·log(1 + (r/c)²)``, which grows only logarithmically for ``r ≫ c``.

Per-landmark weights (0 or 1 for leave-one-out) multiply each landmark's terms.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .objective import NORM_SMOOTHING_MM, AbstractObjective, Errors

LOSS_NAMES = ("l1", "huber", "cauchy")


class AbstractLoss(eqx.Module):
    """A loss ``ρ(r)`` of an error length ``r``, both in mm; ``ρ(r) ≈ r`` is the paper's."""

    name: eqx.AbstractClassVar[str]

    @abc.abstractmethod
    def __call__(self, r_mm: Float[Array, "*n"]) -> Float[Array, "*n"]:
        """The loss of error lengths ``r_mm`` (≥ 0), mm."""


class L1Loss(AbstractLoss):
    """``ρ(r) = r``: the paper's mean error length."""

    name: ClassVar[str] = "l1"

    def __call__(self, r_mm):
        return r_mm


class HuberLoss(AbstractLoss):
    """Quadratic below ``scale_mm``, linear (slope 1) above it."""

    scale_mm: float = eqx.field(static=True)
    name: ClassVar[str] = "huber"

    def __call__(self, r_mm):
        c = self.scale_mm
        return jnp.where(r_mm <= c, r_mm**2 / (2.0 * c), r_mm - 0.5 * c)


class CauchyLoss(AbstractLoss):
    """``(c/2)·log(1 + (r/c)²)``: like Huber near 0, logarithmic for large errors."""

    scale_mm: float = eqx.field(static=True)
    name: ClassVar[str] = "cauchy"

    def __call__(self, r_mm):
        c = self.scale_mm
        return 0.5 * c * jnp.log1p((r_mm / c) ** 2)


def get_loss(name: str, scale_mm: float = 1.0) -> AbstractLoss:
    """The loss called ``name`` (``"l1"``, ``"huber"``, ``"cauchy"``) with scale ``scale_mm``.

    Args:
        name: one of :data:`LOSS_NAMES`.
        scale_mm: where a robust loss turns from quadratic to (sub)linear, mm; > 0. Unused by
            ``l1``.
    """
    if not scale_mm > 0:
        raise ValueError(f"loss scale must be > 0 mm (got {scale_mm})")
    if name == "l1":
        return L1Loss()
    if name == "huber":
        return HuberLoss(float(scale_mm))
    if name == "cauchy":
        return CauchyLoss(float(scale_mm))
    raise ValueError(f"unknown loss {name!r}; known: {', '.join(LOSS_NAMES)}")


def _smoothed_length(e: Float[Array, "n 2"]) -> Float[Array, " n"]:
    return jnp.sqrt(jnp.sum(e**2, axis=-1) + NORM_SMOOTHING_MM**2)


class LossObjective(AbstractObjective):
    """A stage's objective with a loss on each error length and a weight on each landmark.

    Calling it gives ``Σ w·ρ(|e1|)/Σ w + Σ w·ρ(|e2|)/Σ w`` (mm): with ``l1`` and unit
    weights, the paper's F. :meth:`errors` are the base objective's, so reports computed from
    them (F, f1, f2, residuals) stay in the paper's measure.

    Attributes:
        base: the stage's objective (gives the error vectors).
        loss: ``ρ``.
        weights: one non-negative weight per landmark (1 = use, 0 = leave out).
    """

    base: AbstractObjective
    loss: AbstractLoss
    weights: Float[Array, " n"]

    def errors(self, theta: Float[Array, " d"]) -> Errors:
        return self.base.errors(theta)

    def on_landmarks(self, idx: Int[np.ndarray, " m"]) -> LossObjective:
        return LossObjective(self.base.on_landmarks(idx), self.loss, self.weights[idx])

    def __call__(self, theta: Float[Array, " d"]) -> Float[Array, ""]:
        errors = self.errors(theta)
        w = self.weights / jnp.sum(self.weights)
        return sum(
            jnp.sum(w * self.loss(jnp.linalg.norm(e, axis=-1)))
            for e in (errors.image_vs_tablet, errors.hand)
        )

    def landmark_terms(self, errors: Errors) -> Float[Array, " n"]:
        """Each landmark's share of the (smoothed) value, mm: ``w·(ρ(|e1|) + ρ(|e2|))/Σw``;
        twice differentiable, for derivatives per landmark."""
        w = self.weights / jnp.sum(self.weights)
        return w * sum(
            self.loss(_smoothed_length(e)) for e in (errors.image_vs_tablet, errors.hand)
        )

    def residuals(self, theta: Float[Array, " d"]) -> Float[Array, " r"]:
        """Residuals whose sum of squares is the (smoothed) value: ``e·sqrt(w·ρ(|e|))/|e|``."""
        return self.residuals_of(self.errors(theta))

    def residuals_of(self, errors: Errors) -> Float[Array, " r"]:
        """:meth:`residuals` from error vectors already computed (one pass of the chain for a
        caller that needs both)."""
        w = self.weights / jnp.sum(self.weights)

        def scaled(e):
            r = _smoothed_length(e)
            # sqrt(w) apart: a zero weight must give a zero gradient, not 0·∞.
            return (e * (jnp.sqrt(w) * jnp.sqrt(self.loss(r)) / r)[:, None]).reshape(-1)

        return jnp.concatenate([scaled(errors.image_vs_tablet), scaled(errors.hand)])
