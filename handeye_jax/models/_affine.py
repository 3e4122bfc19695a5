"""The stage-2 pair of 2-D affine corrections, eq. (24)."""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from jaxtyping import Array, Float

from .. import geometry as geo
from ._base import AbstractCorrection


def affine_about(
    xy_mm: Float[Array, "n 2"],
    centre_mm: Float[Array, "2"],
    shift_x_mm: Float[Array, ""],
    shift_y_mm: Float[Array, ""],
    theta_deg: Float[Array, ""],
    scale_x: Float[Array, ""],
    scale_y: Float[Array, ""],
) -> Float[Array, "n 2"]:
    """Eq. (24): scale, then rotate about ``centre_mm``, then shift: ``T(X,Y)·T(c)·R·S·T(−c)``."""
    R = geo.rot_z(theta_deg)[:2, :2]
    scaled = (xy_mm - centre_mm) * jnp.stack([scale_x, scale_y])
    return geo.rotate_vectors(R, scaled) + centre_mm + jnp.stack([shift_x_mm, shift_y_mm])


class AffinePair(AbstractCorrection):
    """Two affine maps of five parameters each: shift (X, Y) mm, rotation θ deg, scale Sx, Sy.

    The paper gives no search ranges for stage 2; the defaults admit every value in
    Tables 10 and 11 with room to spare and are overridable by name in ``[search]``.
    """

    X1: Float[Array, ""]
    Y1: Float[Array, ""]
    theta1: Float[Array, ""]
    Sx1: Float[Array, ""]
    Sy1: Float[Array, ""]
    X2: Float[Array, ""]
    Y2: Float[Array, ""]
    theta2: Float[Array, ""]
    Sx2: Float[Array, ""]
    Sy2: Float[Array, ""]

    name: ClassVar[str] = "affine"
    param_names: ClassVar[tuple[str, ...]] = (
        "X1", "Y1", "theta1", "Sx1", "Sy1", "X2", "Y2", "theta2", "Sx2", "Sy2",
    )  # fmt: skip
    # A1 corrects the image chain, A2 the hand positions.
    groups: ClassVar[dict[str, tuple[str, ...]]] = {
        "first": ("X1", "Y1", "theta1", "Sx1", "Sy1"),
        "second": ("X2", "Y2", "theta2", "Sx2", "Sy2"),
    }
    param_units: ClassVar[tuple[str, ...]] = (
        "mm", "mm", "deg", "1", "1", "mm", "mm", "deg", "1", "1",
    )  # fmt: skip
    default_ranges: ClassVar[dict[str, tuple[float, float]]] = {
        "X1": (-10.0, 10.0), "Y1": (-10.0, 10.0), "theta1": (-10.0, 10.0),
        "Sx1": (0.8, 1.2), "Sy1": (0.8, 1.2),
        "X2": (-10.0, 10.0), "Y2": (-10.0, 10.0), "theta2": (-10.0, 10.0),
        "Sx2": (0.8, 1.2), "Sy2": (0.8, 1.2),
    }  # fmt: skip

    def first(self, xy_mm, centre_mm):
        return affine_about(xy_mm, centre_mm, self.X1, self.Y1, self.theta1, self.Sx1, self.Sy1)

    def second(self, xy_mm, centre_mm):
        return affine_about(xy_mm, centre_mm, self.X2, self.Y2, self.theta2, self.Sx2, self.Sy2)
