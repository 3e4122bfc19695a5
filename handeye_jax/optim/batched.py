"""Levenberg–Marquardt for a batch of small least-squares problems at once.

:func:`~handeye_jax.optim.polish.levenberg_marquardt` (optimistix) is right for one polish.
The diagnostics solve well over a hundred small problems (leave-one-out refits, multi-starts
under other conventions), and must stay cheap to compile: a vmapped
``optimistix.least_squares``, or any LM loop compiled into one XLA program, measured several
seconds of tracing and compilation on this project's 2-core machine. Here only the batched
residuals and Jacobians are compiled (the caller's ``fn``, a single small program); the LM
iterations run on the host in NumPy over the whole batch, one call of ``fn`` per iteration.

It keeps :mod:`.polish`'s box transform ``x = lo + (hi − lo)(sin z + 1)/2`` and knows nothing
about what the residuals compute. :func:`levenberg_marquardt_starts` is the same LM from many
starts of one problem (a multi-start search for the best local optimum).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import numpy as np
from jaxtyping import Array, Float

from .. import _xla

#: Damping: start, and the factors after a step that lowers the cost and one that does not.
_LAMBDA0 = 1e-3
_SHRINK = 1.0 / 3.0
_GROW = 4.0
_LAMBDA_RANGE = (1e-12, 1e12)


def residuals_and_jacobian(
    residuals: Callable[[Float[Array, " d"]], Float[Array, " r"]], x: Float[Array, " d"]
) -> tuple[Float[Array, " r"], Float[Array, "r d"]]:
    """``(r(x), ∂r/∂x)`` in one forward-mode pass (the residuals ride along as auxiliary)."""

    def f(x):
        r = residuals(x)
        return r, r

    J, r = jax.jacfwd(f, has_aux=True)(x)
    return r, J


def levenberg_marquardt_batch(
    fn: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    max_steps: int = 300,
    rtol: float = 1e-10,
) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg–Marquardt on B problems at once, each inside the box ``[lower, upper]``.

    Each iteration solves ``(JᵀJ + λ·diag(JᵀJ))·δ = −Jᵀr`` (Marquardt's scaling) for every
    problem in the box coordinates ``z`` and keeps a problem's step only if it lowers its
    ``|r|²``; λ shrinks after an accepted step and grows after a rejected one.

    Args:
        fn: batched residuals and Jacobians: ``x (B, d) -> (r (B, m), J (B, m, d))``. Compile
            it once (e.g. ``jax.jit`` of a ``vmap``); it is called once per iteration.
        x0: starts, ``(B, d)``, inside the box.
        lower, upper: the box, ``(d,)``, finite.
        max_steps: most iterations.
        rtol: stop when no problem's cost fell by more than this fraction for 10 iterations.

    Returns:
        ``(x, cost)``: the end points ``(B, d)`` and their ``|r|²`` ``(B,)``.
    """
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    half = (hi - lo) / 2.0
    z = np.arcsin(np.clip((np.asarray(x0, float) - lo) / half - 1.0, -1.0, 1.0))

    def evaluate(z):
        r, J = (np.asarray(a) for a in fn(lo + half * (np.sin(z) + 1.0)))
        J = J * (half * np.cos(z))[:, None, :]  # chain rule through the box transform
        ok = np.isfinite(r).all(axis=1) & np.isfinite(J).all(axis=(1, 2))
        return r, J, np.where(ok, np.sum(np.where(ok[:, None], r, 0.0) ** 2, axis=1), np.inf)

    r, J, cost = evaluate(z)
    lam = np.full(z.shape[0], _LAMBDA0)
    eye = np.eye(z.shape[1])
    quiet = 0
    for _ in range(max_steps):
        Jt = J.transpose(0, 2, 1)
        H = Jt @ J
        g = (Jt @ r[..., None])[..., 0]
        damping = lam[:, None, None] * (np.diagonal(H, axis1=1, axis2=2)[:, None, :] + 1e-12) * eye
        # H + λ·(diag H + ε) is positive definite for λ > 0: the solve cannot fail.
        dz = -np.linalg.solve(H + damping, g[..., None])[..., 0]
        dz = np.where(np.isfinite(dz), dz, 0.0)
        r_t, J_t, cost_t = evaluate(z + dz)
        better = cost_t < cost
        gain = np.where(better, (cost - cost_t) / np.maximum(cost, 1e-300), 0.0)
        z = np.where(better[:, None], z + dz, z)
        r = np.where(better[:, None], r_t, r)
        J = np.where(better[:, None, None], J_t, J)
        cost = np.where(better, cost_t, cost)
        lam = np.clip(np.where(better, lam * _SHRINK, lam * _GROW), *_LAMBDA_RANGE)
        quiet = quiet + 1 if gain.max() <= rtol else 0
        if quiet >= 10:
            break
    return lo + half * (np.sin(z) + 1.0), cost


# Called once per LM iteration, hence LLVM level 1 (see handeye_jax._xla).
@_xla.fast_compile(llvm_opt_level=1)
def _starts_rj(residuals, X):
    return jax.vmap(lambda x: residuals_and_jacobian(residuals, x))(X)


def levenberg_marquardt_starts(
    residuals: Callable[[Float[Array, " d"]], Float[Array, " r"]],
    starts: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    max_steps: int = 300,
    rtol: float = 1e-10,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`levenberg_marquardt_batch` of one problem from several starts at once.

    Args:
        residuals: residual vector as a function of the parameters; pass an equinox Module's
            method (a pytree) so that repeated calls reuse the compiled program. Its Jacobian
            is taken in forward mode (``d`` JVPs), so the work is linear in the residuals.
        starts: start points ``(B, d)`` inside the box; a fixed ``B`` reuses the program.
        lower, upper: the box, ``(d,)``, finite.
        max_steps, rtol: as for :func:`levenberg_marquardt_batch`.

    Returns:
        ``(x, cost)``: the end points ``(B, d)`` and their ``|r|²`` ``(B,)``.
    """
    return levenberg_marquardt_batch(
        lambda X: _starts_rj(residuals, np.asarray(X)), np.asarray(starts, float), lower, upper,
        max_steps=max_steps, rtol=rtol,
    )  # fmt: skip
