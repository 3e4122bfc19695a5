"""Levenberg–Marquardt inside a box: one solver object, for one problem or a batch of them.

* One problem (:func:`~handeye_jax.optim.minimise`): optimistix's Levenberg–Marquardt, compiled
  into one XLA program, the Jacobian in forward mode (``d`` JVPs: time and memory linear in
  the number of residuals).
* Many problems at once (:func:`minimise_batch`): the same iteration run on the host in NumPy
  over the whole batch, one call of the caller's compiled batched residuals and Jacobians
  per iteration. A vmapped optimistix solve costs seconds more to trace and compile
  (benchmarks/RESULTS.md, "one LM contract"), which a first calibration's diagnostics would
  pay. The multi-start search of one problem (:func:`~handeye_jax.optim.minimise_starts`)
  runs the same iteration compiled whole (:mod:`._multistart`).

Both work in the box coordinates of :mod:`._box` and take the same
:class:`LevenbergMarquardt` configuration.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .._jax import fast_compile
from . import _box
from ._box import Box
from ._solvers import AbstractSolver, BatchSolution, LMSolution, Problem

#: Damping of the batch iteration: start, and the factors after a step that lowers the cost
#: and one that does not.
_LAMBDA0 = 1e-3
_SHRINK = 1.0 / 3.0
_GROW = 4.0
_LAMBDA_RANGE = (1e-12, 1e12)
#: The batch stops after this many iterations in a row in which no problem improved enough.
_QUIET_ITERATIONS = 10
#: Marquardt's scaling, ``diag JᵀJ``, is floored at this fraction of its largest entry.
_SCALE_FLOOR = 1e-6
#: A step is kept only if it lowers ``|r|²`` by at least this fraction of the first-order
#: decrease along it (Armijo's condition; see :func:`sufficient_decrease`).
_SUFFICIENT = 1e-5


def marquardt_scaling(diag: Float[Array, "*b d"]) -> Float[Array, "*b d"]:
    """The damping's scale per coordinate: ``diag JᵀJ``, floored at :data:`_SCALE_FLOOR` of
    the largest (and at 1e-12).

    A coordinate the residuals barely see (a tilt at its sign twin's mirror point, where the
    residuals are even in it) has ``diag ≈ 0``, and a gradient that rounding leaves at 1e-7
    then asks for a step of radians at any damping the others can bear: every step is refused
    until the damping has frozen the others, and LM stops far from the optimum
    (``benchmarks/RESULTS.md``). Floored, that coordinate's step shrinks with the damping like
    the others'; coordinates above the floor are damped as before."""
    xp = _box._xp(diag)
    return xp.maximum(diag, _SCALE_FLOOR * xp.max(diag, axis=-1, keepdims=True)) + 1e-12


def damped_normal_matrix(
    H: Float[Array, "*b d d"], g: Float[Array, "*b d"], z: Float[Array, "*b d"],
    lam: Float[Array, "*b"],
) -> Float[Array, "*b d d"]:
    """The matrix of one LM step's equations, ``(H + λ·D)·δ = −g``, in box coordinates ``z``:
    ``H = JᵀJ`` without the couplings of the coordinates a bound holds (:func:`._box.held`),
    plus λ times :func:`marquardt_scaling` on its diagonal. Both batch LMs solve with it."""
    xp = _box._xp(H, g, z, lam)
    d = H.shape[-1]
    diag = xp.diagonal(H, axis1=-2, axis2=-1)
    damping = lam[..., None] * marquardt_scaling(diag)
    held = _box.held(z, g, diag + damping)
    H = xp.where((held[..., :, None] | held[..., None, :]) & ~xp.eye(d, dtype=bool), 0.0, H)
    # H + λ·(diag H + ε) is positive definite for λ > 0: the solve cannot fail.
    return H + damping[..., :, None] * xp.eye(d)


def sufficient_decrease(
    cost: Float[Array, "*b"], cost_t: Float[Array, "*b"], g: Float[Array, "*b d"],
    z: Float[Array, "*b d"], z_t: Float[Array, "*b d"],
) -> Bool[Array, "*b"]:
    """Whether a trial point ``z_t`` lowers ``|r|²`` from ``cost`` to ``cost_t`` by at least
    :data:`_SUFFICIENT` of the first-order decrease along the step, ``−2·g·(z_t − z)``
    (``g = Jᵀr``, so ``2g`` is the gradient of ``|r|²``).

    Why not any decrease: through the box transform an undamped step of about π + 2z in a
    coordinate folds back, by the sine, to nearly the point it left, lowering the cost a
    little each time. Kept, every such step would shrink the damping, and LM would stop,
    "converged", at an interior point that is not an optimum, never taking the damped step
    towards the bound (``tests/test_de.py``, scipy's bounded least squares). Refused, such a
    step grows the damping instead."""
    xp = _box._xp(cost, cost_t, g, z, z_t)
    first_order = -2.0 * xp.sum(g * (z_t - z), axis=-1)
    return cost_t < cost - _SUFFICIENT * xp.maximum(first_order, 0.0)


class LevenbergMarquardt(AbstractSolver[LMSolution]):
    """Levenberg–Marquardt on ``fn.residuals`` inside the box, from ``x0``.

    Attributes:
        rtol, atol: convergence tolerances. One problem: optimistix's rule (the step and the
            change of the cost each below ``atol + rtol·|value|``). A batch: it stops once no
            problem's cost has fallen by more than ``rtol·cost + atol`` for 10 iterations.
        max_steps: most iterations.
    """

    rtol: float = 1e-12
    atol: float = 1e-12
    max_steps: int = 1000

    def run(self, fn, box, *, x0, key, progress) -> LMSolution:
        del key, progress  # deterministic, and quick enough to need no progress bar
        if x0 is None:
            raise ValueError("Levenberg-Marquardt needs a start point x0")
        x0 = np.clip(np.asarray(x0, dtype=float), box.lower, box.upper)
        x, steps, ok = _lm_compiled(fn, x0, box, self)
        x = np.asarray(x)
        return LMSolution(
            x=x, value=float(_value(fn, x)), steps=int(steps), evaluations=int(steps) + 1,
            converged=bool(ok), start_value=float(_value(fn, x0)),
        )  # fmt: skip


def _lm(fn: Problem, x0, box: Box, lm: LevenbergMarquardt):
    # Imported while tracing only: a run that loads the stored program needs none of it.
    import optimistix as optx

    lower, upper = box.lower, box.upper
    solver = optx.LevenbergMarquardt(rtol=lm.rtol, atol=lm.atol)
    # optimistix evaluates and differentiates the residuals several times while it traces;
    # as a nested jit they are traced once and the rest is reused.
    residuals = eqx.filter_jit(fn.residuals)
    # Forward mode: the Jacobian is d JVPs, O(r·d) time and memory for r residuals. Reverse
    # mode built it from an r × r basis: O(r²) (benchmarks/RESULTS.md, "Scaling with
    # landmarks").
    sol = optx.least_squares(
        lambda z, _: residuals(_box.to_x(z, lower, upper)),
        solver,
        _box.to_z(x0, lower, upper),
        max_steps=lm.max_steps,
        throw=False,
        options={"jac": "fwd"},
    )
    ok = sol.result == optx.RESULTS.successful
    return _box.to_x(sol.value, lower, upper), sol.stats["num_steps"], ok


#: :func:`_lm` compiled (named so in JAX's compile log).
_lm_compiled = fast_compile(_lm)


@fast_compile
def _value(fn: Problem, x):
    return fn(x)


def residuals_and_jacobian(
    residuals: Callable[[Float[Array, " d"]], Float[Array, " r"]], x: Float[Array, " d"]
) -> tuple[Float[Array, " r"], Float[Array, "r d"]]:
    """``(r(x), ∂r/∂x)`` in one forward-mode pass (the residuals ride along as auxiliary)."""

    def f(x):
        r = residuals(x)
        return r, r

    J, r = jax.jacfwd(f, has_aux=True)(x)
    return r, J


def minimise_batch(
    fn: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    solver: LevenbergMarquardt,
    box: Box,
    x0: Float[ArrayLike, "b d"],
) -> BatchSolution:
    """Levenberg–Marquardt on B problems at once, each inside ``bounds``.

    Each iteration solves ``(JᵀJ + λ·D)·δ = −Jᵀr``, ``D`` Marquardt's scaling ``diag(JᵀJ)``
    floored (:func:`marquardt_scaling`), for every problem in the box coordinates ``z`` and
    keeps a problem's step only if it lowers its ``|r|²`` by enough
    (:func:`sufficient_decrease`); λ shrinks after an accepted step and grows after a rejected
    one. A parameter on a bound is held there while the cost pushes it outward (an active
    set, as :func:`~handeye_jax.optim.minimise_starts`).

    Args:
        fn: batched residuals and Jacobians: ``x (B, d) -> (r (B, m), J (B, m, d))``. Compile
            it once (e.g. ``jax.jit`` of a ``vmap``); it is called once per iteration.
        solver: the tolerances and the most iterations.
        box: the search box, the same for every problem.
        x0: starts, ``(B, d)``.
    """
    lo, hi = box.lower, box.upper
    z = _box.to_z(np.asarray(x0, float), lo, hi)

    def evaluate(z):
        r, J = (np.asarray(a) for a in fn(_box.to_x(z, lo, hi)))
        J = J * _box.dx_dz(z, lo, hi)[:, None, :]  # chain rule through the box transform
        ok = np.isfinite(r).all(axis=1) & np.isfinite(J).all(axis=(1, 2))
        return r, J, np.where(ok, np.sum(np.where(ok[:, None], r, 0.0) ** 2, axis=1), np.inf)

    r, J, cost = evaluate(z)
    lam = np.full(z.shape[0], _LAMBDA0)
    quiet = steps = 0
    for steps in range(1, solver.max_steps + 1):  # noqa: B007 (steps is reported)
        Jt = J.transpose(0, 2, 1)
        H = Jt @ J
        g = (Jt @ r[..., None])[..., 0]
        dz = -np.linalg.solve(damped_normal_matrix(H, g, z, lam), g[..., None])[..., 0]
        dz = np.where(np.isfinite(dz), dz, 0.0)
        z_t = _box.step(z, dz)
        r_t, J_t, cost_t = evaluate(z_t)
        better = sufficient_decrease(cost, cost_t, g, z, z_t)
        gain = np.where(better, cost - cost_t, 0.0)
        enough = gain > solver.rtol * np.where(np.isfinite(cost), cost, 0.0) + solver.atol
        z = np.where(better[:, None], z_t, z)
        r = np.where(better[:, None], r_t, r)
        J = np.where(better[:, None, None], J_t, J)
        cost = np.where(better, cost_t, cost)
        lam = np.clip(np.where(better, lam * _SHRINK, lam * _GROW), *_LAMBDA_RANGE)
        quiet = 0 if enough.any() else quiet + 1
        if quiet >= _QUIET_ITERATIONS:
            break
    return BatchSolution(x=_box.to_x(z, lo, hi), value=cost, steps=steps, evaluations=steps + 1,
                         converged=quiet >= _QUIET_ITERATIONS)  # fmt: skip
