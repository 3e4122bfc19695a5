"""Problems of different sizes made one shape, for a batch: observations padded with rows of
weight 0, and an objective that gives those rows no weight.

A padded row is a copy of the first row (finite, so its error is finite and, times its
weight 0, adds exactly nothing). For up to ``UNROLL_LANDMARKS`` rows the mean error length is
summed row after row, as :class:`~handeye_jax.LengthBlock` sums it, so a padded problem's
value is its unpadded value bit for bit; its residuals are the unpadded ones with zeros
interleaved. Heights (``hand_z``) enter through means over the rows (the profiled vertical
offsets), which padding would shift: such observations are not padded.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..data import Observations
from ._objective import (
    _LANDMARK_FIELDS,
    _ROW_FIELDS,
    NORM_SMOOTHING_MM,
    UNROLL_LANDMARKS,
    AbstractBlock,
    AbstractObjective,
    GaussianBlock,
    LengthBlock,
    WeightedLengthBlock,
    _length,
)


def pad_rows(obs: Observations, n: int) -> tuple[Observations, np.ndarray]:
    """``obs`` with copies of its first row appended up to ``n`` rows, and the rows' weights
    (1 for the data's rows, 0 for the copies).

    Raises:
        ValueError: for observations with the hand's heights (see the module docstring), or
            more rows than ``n``.
    """
    m = obs.n_landmarks
    if m > n:
        raise ValueError(f"cannot pad {m} rows to {n}")
    mask = np.concatenate([np.ones(m), np.zeros(n - m)])
    if m == n:
        return obs, mask
    if obs.hand_z_mm is not None:
        raise ValueError("observations with hand heights cannot be padded")
    fields = _LANDMARK_FIELDS + tuple(f for f in _ROW_FIELDS if getattr(obs, f) is not None)
    rows = np.concatenate([np.arange(m), np.zeros(n - m, int)])
    return dataclasses.replace(obs, **{f: np.asarray(getattr(obs, f))[rows] for f in fields}), mask


def _masked_mean(x: Float[Array, " n"], mask: Float[Array, " n"]) -> Float[Array, ""]:
    # Row after row up to UNROLL_LANDMARKS rows, as LengthBlock's mean is taken: a padded
    # row's 0·x adds exactly nothing, and the sum of the weights is exactly the rows' count.
    n = x.shape[0]
    if n > UNROLL_LANDMARKS:
        return jnp.sum(mask * x) / jnp.sum(mask)
    return sum(mask[m] * x[m] for m in range(n)) / sum(mask[m] for m in range(n))


class MaskedLengthBlock(AbstractBlock):
    """:class:`~handeye_jax.LengthBlock` with a weight 1 or 0 per row (a padded row: 0).

    Attributes:
        errors: one error vector per row, mm.
        mask: 1 for a row of data, 0 for padding.
    """

    errors: Float[Array, "n 2"]
    mask: Float[Array, " n"]

    def value(self):
        return _masked_mean(_length(self.errors), self.mask)

    def residuals(self):
        e = self.errors
        w = (jnp.sum(e**2, axis=-1, keepdims=True) + NORM_SMOOTHING_MM**2) ** -0.25
        return (e * w * self.mask[:, None] / jnp.sqrt(jnp.sum(self.mask))).reshape(-1)


def _masked(block: AbstractBlock, mask: Float[Array, " n"]) -> AbstractBlock:
    if isinstance(block, LengthBlock):
        return MaskedLengthBlock(block.errors, mask)
    if isinstance(block, WeightedLengthBlock):
        return WeightedLengthBlock(block.errors, block.weights * mask, block.loss)
    if isinstance(block, GaussianBlock):
        return GaussianBlock(block.errors, block.scale, block.weights * mask)
    return block  # a prior's: no rows


class MaskedObjective(AbstractObjective):
    """Another objective on padded observations (:func:`pad_rows`), its padding given no
    weight: each data block's rows are weighed by ``mask``; a prior's block is unchanged.

    Attributes:
        base: the objective on the padded observations (loss and prior included).
        mask: 1 for a row of data, 0 for padding, ``(n,)``.
    """

    base: AbstractObjective
    mask: Float[Array, " n"]

    def blocks(self, theta):
        return {k: _masked(b, self.mask) for k, b in self.base.blocks(theta).items()}

    def on_landmarks(self, idx):
        return MaskedObjective(self.base.on_landmarks(idx), jnp.asarray(self.mask)[idx])
