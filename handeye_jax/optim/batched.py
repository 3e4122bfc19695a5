"""A traceable Levenberg–Marquardt for many small least-squares problems at once (``vmap``).

:func:`~handeye_jax.optim.polish.levenberg_marquardt` uses optimistix and returns NumPy
results: right for one polish. The diagnostics solve dozens of small problems (leave-one-out
refits, multi-starts under other conventions) and must stay cheap to compile: a vmapped
``optimistix.least_squares`` measured 1.4 s to trace and 1.6 s to compile per call site on
this project's 2-core machine, while this fixed-step loop of ~20 operations traces in a
fraction of that. It keeps :mod:`.polish`'s box transform ``x = lo + (hi − lo)(sin z + 1)/2``
and knows nothing about what the residuals compute.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .polish import _Box

#: Damping factors: start, and the factor it shrinks by after a step that lowers the cost
#: (it grows by ``_GROW`` after one that does not; Nielsen's classic choices are close).
_LAMBDA0 = 1e-3
_SHRINK = 1.0 / 3.0
_GROW = 4.0


def levenberg_marquardt_steps(
    residuals: Callable[[Float[Array, " d"]], Float[Array, " r"]],
    x0: Float[Array, " d"],
    lower: Float[Array, " d"],
    upper: Float[Array, " d"],
    *,
    steps: int = 200,
) -> tuple[Float[Array, " d"], Float[Array, ""]]:
    """``steps`` Levenberg–Marquardt iterations from ``x0`` inside the box; traceable.

    Each iteration solves ``(JᵀJ + λ·diag(JᵀJ))·δ = −Jᵀr`` (Marquardt's scaling) in the box
    coordinates ``z`` and keeps the step only if it lowers ``|r|²``. A fixed count, so a
    ``vmap`` over problems is one loop with no data-dependent exit; a converged problem just
    stops moving.

    Args:
        residuals: residual vector as a function of the parameters (pass a bound method of an
            equinox Module so ``vmap`` may batch the Module's arrays).
        x0: start, inside the box.
        lower, upper: the box (finite).
        steps: iterations, static.

    Returns:
        ``(x, cost)``: the end point and ``|r(x)|²``.
    """
    box = _Box(lower, upper)

    def res_and_jac(z):
        # One forward-mode pass gives both: the residuals ride along as the auxiliary output.
        def f(z):
            r = residuals(box.to_x(z))
            return r, r

        J, r = jax.jacfwd(f, has_aux=True)(z)
        ok = jnp.all(jnp.isfinite(r)) & jnp.all(jnp.isfinite(J))
        return r, J, jnp.where(ok, jnp.sum(r**2), jnp.inf)

    def propose(z, r, J, lam):
        H = J.T @ J
        damping = lam * (jnp.diag(H) + 1e-12)
        return z + jnp.linalg.solve(H + jnp.diag(damping), -(J.T @ r))

    # The carry holds the accepted point with its residuals and Jacobian, and a trial point;
    # each iteration evaluates only the trial (one pass of the residuals), then keeps it if
    # it lowers the cost and proposes the next trial from whichever point it kept.
    def body(_, carry):
        z, r, J, c, lam, z_try = carry
        r_t, J_t, c_t = res_and_jac(z_try)
        better = c_t < c
        z, r, J, c = (
            jnp.where(better, a, b) for a, b in ((z_try, z), (r_t, r), (J_t, J), (c_t, c))
        )
        lam = jnp.clip(jnp.where(better, lam * _SHRINK, lam * _GROW), 1e-12, 1e12)
        return z, r, J, c, lam, propose(z, r, J, lam)

    # The first iteration evaluates the start itself (against an infinite cost), so the
    # residuals are traced once, inside the loop.
    z0 = box.to_z(x0)
    r_shape = jax.eval_shape(residuals, x0).shape
    r0, J0 = jnp.zeros(r_shape, z0.dtype), jnp.zeros((*r_shape, *z0.shape), z0.dtype)
    init = (z0, r0, J0, jnp.asarray(jnp.inf, z0.dtype), jnp.asarray(_LAMBDA0 / _SHRINK), z0)
    z, _, _, c, _, _ = jax.lax.fori_loop(0, steps + 1, body, init)
    return box.to_x(z), c
