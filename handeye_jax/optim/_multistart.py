"""Levenberg–Marquardt from many starts at once, compiled whole: one XLA program runs every
iteration of every start, with no trip to the host between iterations (a batch of problems:
:func:`~handeye_jax.optim.minimise_starts_many`).

The iteration is :func:`~handeye_jax.optim.minimise_batch`'s (Marquardt's scaling, a step
kept only if it lowers its start's ``|r|²`` by enough (``_lm.sufficient_decrease``), λ shrunk
after a kept step and grown after a refused one, a stop once no start has improved enough for
10 iterations), written so that its arithmetic is the same bit for bit whatever rows of zeros
pad a problem's residuals:

* the sums over residual rows (``|r|²``, ``JᵀJ``, ``Jᵀr``) are taken row after row, in
  order, so a padded row of zeros adds exactly nothing;
* the damped normal equations (positive definite for λ > 0) are solved by LAPACK's Cholesky
  factorisation and triangular solves, one start's matrix per call: a start's step is the
  same whatever the other starts or problems of the batch.

It works in the box coordinates of :mod:`._box`, as the other LM does, with bounds kept as an
active set there (:func:`._box.held`, :func:`._box.step`): a coordinate on a bound takes its
step in ``x``, clipped onto the box, and one pushed outward leaves the normal equations.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._jax import fast_compile, in_float64
from . import _box
from ._box import Box
from ._lm import (
    _GROW,
    _LAMBDA0,
    _LAMBDA_RANGE,
    _QUIET_ITERATIONS,
    _SHRINK,
    LevenbergMarquardt,
    damped_normal_matrix,
    residuals_and_jacobian,
    sufficient_decrease,
)
from ._solvers import BatchSolution, Problem


class _State(eqx.Module):
    z: Float[Array, "s d"]
    r: Float[Array, "s m"]
    J: Float[Array, "s m d"]
    cost: Float[Array, " s"]
    lam: Float[Array, " s"]
    quiet: Int[Array, ""]
    steps: Int[Array, ""]
    fresh: Bool[Array, ""]  # r, J and cost are not yet the starts': the first pass takes them


def _rows_sum(term, m: int):
    """``term(0) + term(1) + … + term(m − 1)``, one row after another (a padded row of zeros
    adds exactly 0); ``term(k)`` is row ``k``'s share."""
    return jax.lax.fori_loop(1, m, lambda k, acc: acc + term(k), term(0))


def _evaluate(fn: Problem, z, lower, upper):
    x = _box.to_x(z, lower, upper)
    r, J = jax.vmap(lambda x: residuals_and_jacobian(fn.residuals, x))(x)
    J = J * _box.dx_dz(z, lower, upper)[:, None, :]  # the chain rule through the box transform
    ok = jnp.isfinite(r).all(axis=1) & jnp.isfinite(J).all(axis=(1, 2))
    r0 = jnp.where(ok[:, None], r, 0.0)
    return r, J, jnp.where(ok, _rows_sum(lambda k: r0[:, k] * r0[:, k], r.shape[1]), jnp.inf)


def _cholesky_solve(A: Float[Array, "s d d"], b: Float[Array, "s d"]) -> Float[Array, "s d"]:
    """``A⁻¹b`` for symmetric positive definite ``A``, each start's on its own (LAPACK's potrf
    and trsm). Unrolled in XLA, the factorisation of a 12 × 12 matrix was about 300 scalar
    operations per start, which made the restarts' program the largest a calibration compiles
    (``benchmarks/RESULTS.md``)."""
    L = jax.lax.linalg.cholesky(A, symmetrize_input=False)  # A is symmetric as built
    return jax.scipy.linalg.cho_solve((L, True), b[..., None])[..., 0]


def _step(fn: Problem, lower, upper, lm: LevenbergMarquardt, st: _State) -> _State:
    J, r = st.J, st.r
    m = r.shape[1]
    H = _rows_sum(lambda k: J[:, k, :, None] * J[:, k, None, :], m)
    g = _rows_sum(lambda k: J[:, k] * r[:, k, None], m)
    dz = -_cholesky_solve(damped_normal_matrix(H, g, st.z, st.lam), g)
    dz = jnp.where(jnp.isfinite(dz), dz, 0.0)
    z_t = _box.step(st.z, dz)
    r_t, J_t, cost_t = _evaluate(fn, z_t, lower, upper)
    better = sufficient_decrease(st.cost, cost_t, g, st.z, z_t)
    gain = jnp.where(better, st.cost - cost_t, 0.0)
    enough = gain > lm.rtol * jnp.where(jnp.isfinite(st.cost), st.cost, 0.0) + lm.atol
    lam = jnp.clip(jnp.where(better, st.lam * _SHRINK, st.lam * _GROW), *_LAMBDA_RANGE)
    # The first pass (r = J = 0, so dz = −0.0 and z + dz is z) evaluates the starts: it is
    # neither a step nor a refusal, and its r and J are kept even where they are not finite.
    take = better | st.fresh
    return _State(
        z=jnp.where(better[:, None], z_t, st.z),
        r=jnp.where(take[:, None], r_t, r),
        J=jnp.where(take[:, None, None], J_t, J),
        cost=jnp.where(better, cost_t, st.cost),
        lam=jnp.where(st.fresh, st.lam, lam),
        quiet=jnp.where(st.fresh | enough.any(), 0, st.quiet + 1),
        steps=jnp.where(st.fresh, st.steps, st.steps + 1),
        fresh=jnp.asarray(False),
    )


def _starts_loop(fn: Problem, x0, lower, upper, lm: LevenbergMarquardt, run: Bool[Array, ""]):
    """LM from the starts ``x0`` (s, d) of one problem: end points, costs, iterations and
    whether the batch's stopping rule held. ``run`` False returns the starts untouched."""
    z = _box.to_z(x0, lower, upper)
    # The starts are evaluated by the loop's first pass, not before it: the residuals and
    # their Jacobian then appear once in the program (a quarter to a third less to compile).
    # The state's shapes from one start's residuals: tracing _evaluate for them would trace
    # the Jacobian of every start once more (a tenth of a cold calibration's tracing).
    r = jax.eval_shape(fn.residuals, jax.ShapeDtypeStruct(x0.shape[1:], x0.dtype))
    s, m, d = z.shape[0], r.shape[0], z.shape[1]
    dtype = jnp.result_type(r.dtype, z.dtype)  # J is ∂r/∂x times dx/dz
    st = _State(z, jnp.zeros((s, m), r.dtype), jnp.zeros((s, m, d), dtype),
                jnp.full(s, jnp.inf, r.dtype), jnp.full(s, _LAMBDA0),
                jnp.asarray(0), jnp.asarray(0), jnp.asarray(True))  # fmt: skip
    limit = jnp.where(run, lm.max_steps, 0)

    def going(st):
        return st.fresh | (st.steps < limit) & (st.quiet < _QUIET_ITERATIONS)

    st = jax.lax.while_loop(going, lambda st: _step(fn, lower, upper, lm, st), st)
    x = _box.to_x(st.z, lower, upper)
    return x, st.cost, st.steps, st.quiet >= _QUIET_ITERATIONS


# At LLVM level 0: the package calls it with one start (the ML polish, the mirror check),
# which level 1 compiled about 0.4 s longer to run no faster (benchmarks/RESULTS.md). Many
# starts of one problem run slower at level 0; the restarts use `_starts`, at level 1.
@fast_compile
def _one(fn, x0, lower, upper, lm, run):
    return _starts_loop(fn, x0, lower, upper, lm, run)


def _config(lm: LevenbergMarquardt) -> LevenbergMarquardt:
    # NumPy scalars, so that other tolerances reuse the compiled program.
    return LevenbergMarquardt(
        rtol=np.asarray(lm.rtol, float), atol=np.asarray(lm.atol, float),
        max_steps=np.asarray(lm.max_steps, np.int64),
    )  # fmt: skip


@in_float64
def minimise_starts(
    fn: Problem, solver: LevenbergMarquardt, box: Box, starts: Float[ArrayLike, "s d"]
) -> BatchSolution:
    """Levenberg–Marquardt on one problem from several starts at once (a multi-start search
    for its lowest local optimum), compiled whole.

    Each iteration solves ``(JᵀJ + λ·D)·δ = −Jᵀr``, ``D`` Marquardt's scaling ``diag(JᵀJ)``
    floored (:func:`~handeye_jax.optim._lm.damped_normal_matrix`), for every start in the box
    coordinates and keeps a start's step only if it lowers its ``|r|²`` by enough (at least
    1e-5 of the first-order decrease along it); λ shrinks after a kept step and grows after a
    refused one. A parameter on a bound is held there while the cost pushes it outward (an
    active set), so an optimum on a bound is reached, not stalled before. All starts stop
    together, once none has lowered its cost by more than ``rtol·cost + atol`` for 10
    iterations, or after ``max_steps``.

    Args:
        fn: the problem; pass an equinox Module so repeated calls reuse the compiled program.
            Its Jacobian is taken in forward mode, so the work is linear in the residuals.
        solver: the tolerances and the most iterations.
        box: the search box.
        starts: start points ``(s, d)``; a fixed ``s`` reuses the program.

    Returns:
        ``x`` ``(s, d)``, ``value`` each start's ``|r|²`` ``(s,)`` (``inf`` where not finite).
    """
    x0 = np.asarray(starts, float)
    x, cost, steps, ok = _one(fn, x0, box.lower, box.upper, _config(solver), np.asarray(True))
    steps = int(steps)
    return BatchSolution(x=np.asarray(x), value=np.asarray(cost), steps=steps,
                         evaluations=steps + 1, converged=bool(ok))  # fmt: skip
