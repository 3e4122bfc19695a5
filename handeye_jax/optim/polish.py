"""Box-constrained Levenberg–Marquardt polish with optimistix. Knows only residual functions.

optimistix's LM is unconstrained. Bounds are kept by an active set: when LM ends outside the
box, the parameters that left it are pinned to the bound they crossed and LM runs again on
the others, until the end point is inside the box.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float


@dataclass(frozen=True)
class PolishResult:
    """``x``: where LM stopped, inside the box; ``steps``: LM steps over all rounds;
    ``solver_ok``: optimistix reported convergence in the last round; ``pinned``: indices of
    parameters held on a bound."""

    x: np.ndarray
    steps: int
    solver_ok: bool
    pinned: tuple[int, ...]


@eqx.filter_jit
def _lm(
    residuals: Callable,
    x0: Float[Array, " d"],
    free: Bool[Array, " d"],
    rtol: float,
    atol: float,
    max_steps: int,
):
    def fn(y, _):
        return residuals(jnp.where(free, y, x0))

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    sol = optx.least_squares(fn, solver, x0, max_steps=max_steps, throw=False)
    x = jnp.where(free, sol.value, x0)
    return x, sol.stats["num_steps"], sol.result == optx.RESULTS.successful


def levenberg_marquardt(
    residuals: Callable[[Float[Array, " d"]], Float[Array, " r"]],
    x0: Float[ArrayLike, " d"],
    lower: Float[ArrayLike, " d"] | None = None,
    upper: Float[ArrayLike, " d"] | None = None,
    *,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    max_steps: int = 500,
) -> PolishResult:
    """Minimise ``sum(residuals(x)**2)`` from ``x0`` inside ``[lower, upper]`` (optional)."""
    x = jnp.asarray(x0, dtype=float)
    d = x.shape[0]
    lower = jnp.full(d, -jnp.inf) if lower is None else jnp.asarray(lower, dtype=float)
    upper = jnp.full(d, jnp.inf) if upper is None else jnp.asarray(upper, dtype=float)
    free = np.ones(d, dtype=bool)
    total_steps, ok = 0, False
    for _ in range(d + 1):
        x_new, steps, ok = _lm(residuals, x, jnp.asarray(free), rtol, atol, max_steps)
        total_steps += int(steps)
        outside = np.asarray((x_new < lower) | (x_new > upper))
        if not outside.any():
            x = x_new
            break
        free &= ~outside
        x = jnp.where(jnp.asarray(outside), jnp.clip(x_new, lower, upper), x)
    return PolishResult(
        x=np.asarray(x),
        steps=total_steps,
        solver_ok=bool(ok),
        pinned=tuple(int(i) for i in np.flatnonzero(~free)),
    )
