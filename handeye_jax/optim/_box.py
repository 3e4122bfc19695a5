"""The search box (:class:`Box`, the one box type) and its transform
``x = lo + (hi − lo)·(sin z + 1)/2``.

Levenberg–Marquardt is unconstrained; bounds are kept as MINUIT keeps them: LM works on ``z``,
which the transform maps into the box smoothly, so the residuals and their minimiser are
unchanged inside the box. The functions take NumPy or JAX arrays and return the same kind.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float


def _xp(*arrays):
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np


def to_x(z: Float[Array, "*b d"], lower: Float[Array, " d"], upper: Float[Array, " d"]):
    """Box coordinates ``z`` to parameters ``x`` (always inside ``[lower, upper]``)."""
    xp = _xp(z, lower, upper)
    return lower + (upper - lower) * (xp.sin(z) + 1.0) / 2.0


def to_z(x: Float[Array, "*b d"], lower: Float[Array, " d"], upper: Float[Array, " d"]):
    """Parameters ``x`` (clipped into the box) to box coordinates ``z`` in ``[−π/2, π/2]``."""
    xp = _xp(x, lower, upper)
    return xp.arcsin(xp.clip(2.0 * (x - lower) / (upper - lower) - 1.0, -1.0, 1.0))


#: A coordinate is at a bound when ``|cos z|`` is below this (within about 0.25 % of its range).
_AT_BOUND = 0.1
#: A step onto a bound stops this short of it (in ``sin z``), so that the coordinate's column of
#: the Jacobian, ``∂x/∂z``, is not exactly 0 there and a later step can leave the bound.
_EDGE = 1.0 - 1e-12


def step(z: Float[Array, "*b d"], dz: Float[Array, "*b d"]):
    """The trial point of an LM step ``dz`` in box coordinates: ``z + dz``, except at a bound.

    At a bound ``∂x/∂z = 0``, so the linear model of the residuals in ``z`` is flat there and
    its step in that coordinate is large and meaningless (the sine folds it back anywhere in
    the box): LM refuses it, grows its damping, and can stop before any step is taken. A
    coordinate at a bound takes instead the step its linear model gives in ``x``,
    ``sin z + cos z·dz``, clipped onto the box: a projected step. Elsewhere, and where
    ``dz`` is 0, the trial point is ``z + dz`` bit for bit: a step that leaves the box from
    further in is still folded back, which the multi-start searches' long first steps from
    uniform starts rely on (projected onto the box, one twin's refits no longer found its
    lower basin: ``tests/test_diagnostics.py``).
    """
    xp = _xp(z, dz)
    s, c = xp.sin(z), xp.cos(z)
    project = (xp.abs(c) < _AT_BOUND) & (dz != 0)
    return xp.where(project, xp.arcsin(xp.clip(s + c * dz, -_EDGE, _EDGE)), z + dz)


def held(z: Float[Array, "*b d"], g: Float[Array, "*b d"], damped: Float[Array, "*b d"]):
    """The coordinates an LM step decouples from the others: at a bound (as :func:`step` has
    it), where the coordinate's own damped step, ``−g/damped`` (``g`` the cost's gradient in
    ``z``, ``damped`` the diagonal of the damped normal equations), would leave the box.

    Such a step is clipped onto the bound, so a step of the others solved jointly with it
    would assume a move that is not made (projected, it crawls along the bound). Its couplings
    in the normal equations are dropped: it takes its own step, clipped, and the others the
    step of the problem without it (an active set). Where none is held, the equations are
    unchanged, bit for bit.
    """
    xp = _xp(z, g, damped)
    s, c = xp.sin(z), xp.cos(z)
    return (xp.abs(c) < _AT_BOUND) & (xp.abs(s - c * g / damped) > _EDGE)


def dx_dz(z: Float[Array, "*b d"], lower: Float[Array, " d"], upper: Float[Array, " d"]):
    """``∂x/∂z``, elementwise (the chain rule's factor for a Jacobian in ``z``)."""
    xp = _xp(z, lower, upper)
    return (upper - lower) / 2.0 * xp.cos(z)


class Box(eqx.Module):
    """A search box: ``lower < upper``, finite, one entry per parameter (in its unit); or a
    batch of boxes, one row per problem (``(b, d)``, for :func:`~handeye_jax.optim.minimise_many`).

    Built from concrete values it is checked and held as float64 NumPy arrays; it is a pytree,
    so it also passes through ``jit`` and ``vmap`` (as the notebooks and
    ``benchmarks/convergence.py`` run optimistix in box coordinates).
    """

    lower: Float[Array, "*b d"]
    upper: Float[Array, "*b d"]

    def __init__(self, lower: Float[ArrayLike, "*b d"], upper: Float[ArrayLike, "*b d"]):
        if isinstance(lower, jax.core.Tracer) or isinstance(upper, jax.core.Tracer):
            self.lower, self.upper = lower, upper  # inside a traced function: not checked
            return
        lo, hi = np.array(lower, dtype=np.float64), np.array(upper, dtype=np.float64)
        if lo.ndim != 2 or hi.ndim != 2:  # one box: any shape of d numbers
            lo, hi = lo.reshape(-1), hi.reshape(-1)
        if lo.shape != hi.shape:
            raise ValueError(f"bounds differ in shape: {lo.shape} and {hi.shape}")
        if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()):
            raise ValueError("bounds must be finite with lower < upper in every parameter")
        self.lower, self.upper = lo, hi

    @property
    def d(self) -> int:
        """The number of parameters."""
        return self.lower.shape[-1]

    def to_x(self, z):
        """Box coordinates to parameters (see :func:`to_x`)."""
        return to_x(z, self.lower, self.upper)

    def to_z(self, x):
        """Parameters to box coordinates (see :func:`to_z`)."""
        return to_z(x, self.lower, self.upper)
