"""Per-landmark losses and weights on top of a stage's objective: the robust option and LOO.

The paper's F is the mean Euclidean error length of each term. A loss ``ρ`` replaces the
length ``r`` of each error vector by ``ρ(r)`` (mm), so one bad touch pulls the fit less:

* ``ml``: the maximum-likelihood fit under the noise model (the default,
  :mod:`handeye_jax.problem._noise`); its search runs on the paper's F, as ``l1``'s;
* ``l1``: ``ρ(r) = r``, the paper's F;
* ``huber``: ``r²/(2c)`` below the scale ``c``, ``r − c/2`` above it;
* ``cauchy``: ``(c/2)·log(1 + (r/c)²)``, which grows only logarithmically for ``r ≫ c``.

Per-landmark weights (0 or 1 for leave-one-out) multiply each landmark's terms: see
:class:`~handeye_jax.LossObjective`.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

LOSS_NAMES = ("ml", "l1", "huber", "cauchy")


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
    """The loss called ``name`` (``"ml"``, ``"l1"``, ``"huber"``, ``"cauchy"``) with scale
    ``scale_mm``. ``ml``'s is the paper's (the search for the optimum's basin); the noise
    model then refines the optimum (:class:`~handeye_jax.NoiseObjective`).

    Args:
        name: one of :data:`LOSS_NAMES`.
        scale_mm: where a robust loss turns from quadratic to (sub)linear, mm; > 0. Unused by
            ``l1``.
    """
    if not scale_mm > 0:
        raise ValueError(f"loss scale must be > 0 mm (got {scale_mm})")
    if name in ("ml", "l1"):
        return L1Loss()
    if name == "huber":
        return HuberLoss(float(scale_mm))
    if name == "cauchy":
        return CauchyLoss(float(scale_mm))
    raise ValueError(f"unknown loss {name!r}; known: {', '.join(LOSS_NAMES)}")
