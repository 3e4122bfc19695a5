"""Box-constrained Levenberg–Marquardt polish with optimistix. Knows only residual functions.

optimistix's LM is unconstrained. Bounds are kept as MINUIT keeps them: LM works on ``z`` with
``x = lo + (hi − lo)·(sin z + 1)/2``, which maps every ``z`` into the box and is smooth, so
the residuals and their minimiser are unchanged inside the box. Parameters without finite
bounds are polished as they are.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float

from .. import _xla


@dataclass(frozen=True)
class PolishResult:
    """``x``: where LM stopped (inside the box); ``steps``: LM steps taken; ``solver_ok``:
    optimistix reported convergence (a stop at ``max_steps`` is not a failure of the point)."""

    x: np.ndarray
    steps: int
    solver_ok: bool


class _Box(eqx.Module):
    lower: Float[Array, " d"]
    upper: Float[Array, " d"]

    @property
    def bounded(self):
        return jnp.isfinite(self.lower) & jnp.isfinite(self.upper)

    def _finite(self):
        # Dummy finite bounds where unbounded, so the unused branch never makes NaN gradients.
        b = self.bounded
        return jnp.where(b, self.lower, 0.0), jnp.where(b, self.upper, 1.0)

    def to_x(self, z):
        lo, hi = self._finite()
        return jnp.where(self.bounded, lo + (hi - lo) * (jnp.sin(z) + 1.0) / 2.0, z)

    def to_z(self, x):
        lo, hi = self._finite()
        u = 2.0 * (x - lo) / (hi - lo) - 1.0
        return jnp.where(self.bounded, jnp.arcsin(jnp.clip(u, -1.0, 1.0)), x)


def _lm(residuals: Callable, x0, box: _Box, rtol: float, atol: float, max_steps: int):
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    # optimistix evaluates and differentiates the residuals several times while it traces;
    # as a nested jit they are traced once and the rest is reused: about 0.4 s less tracing
    # for the paper's stage 1 (measured).
    residuals = eqx.filter_jit(residuals)
    # Forward mode: the Jacobian is d JVPs, O(r·d) time and memory for r residuals, and the
    # QR of the damped system is O(r·d²). Reverse mode materialised it with one backward pass
    # per residual from an r × r basis: O(r²), 95 s of a 300-landmark fit and a 60 GB
    # allocation at 10,000 (benchmarks/RESULTS.md, "Scaling with landmarks").
    sol = optx.least_squares(
        lambda z, _: residuals(box.to_x(z)),
        solver,
        box.to_z(x0),
        max_steps=max_steps,
        throw=False,
        options={"jac": "fwd"},
    )
    return box.to_x(sol.value), sol.stats["num_steps"], sol.result == optx.RESULTS.successful


#: :func:`_lm` compiled (named so in JAX's compile log).
_lm_compiled = _xla.fast_compile(_lm)


def levenberg_marquardt(
    residuals: Callable[[Float[Array, " d"]], Float[Array, " r"]],
    x0: Float[ArrayLike, " d"],
    lower: Float[ArrayLike, " d"] | None = None,
    upper: Float[ArrayLike, " d"] | None = None,
    *,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    max_steps: int = 1000,
) -> PolishResult:
    """Minimise ``sum(residuals(x)**2)`` from ``x0``, inside ``[lower, upper]`` if given.

    Args:
        residuals: residual vector as a function of the parameters.
        x0: start point (inside the box).
        lower, upper: the box; ``None`` or infinite entries mean unbounded.
        rtol, atol: optimistix's convergence tolerances.
        max_steps: most LM steps.
    """
    x0 = jnp.asarray(x0, dtype=float)
    d = x0.shape[0]
    lower = jnp.full(d, -jnp.inf) if lower is None else jnp.asarray(lower, dtype=float)
    upper = jnp.full(d, jnp.inf) if upper is None else jnp.asarray(upper, dtype=float)
    x, steps, ok = _lm_compiled(residuals, x0, _Box(lower, upper), rtol, atol, max_steps)
    return PolishResult(x=np.asarray(x), steps=int(steps), solver_ok=bool(ok))
