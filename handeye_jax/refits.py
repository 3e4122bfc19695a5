"""Batched refits for the diagnostics: leave-one-out for both stages, and the hand-angle
conventions, with two small compiled programs (batched residuals and Jacobians per stage).

* **Leave-one-out, stage 1.** For each landmark m, Levenberg–Marquardt from the full optimum
  on the stage-1 objective with landmark m's weight set to 0; the held-out error is the refit
  model's error at landmark m.
* **Leave-one-out, stage 2 (the whole pipeline).** Stage 2 is fitted to stage 1's points, so
  an honest held-out error refits both: the stage-1 refit without m gives the points, stage 2
  is refitted on them without m (from the full stage-2 optimum), and landmark m is predicted.
  The centre of rotation stays landmark ``centre_index``'s mapped image point (an input, not a
  touch), as in deployment.
* **Conventions.** Stage 1 refitted under each hand-angle convention ``φ = zero + sign·θh``,
  zero ∈ {0, 90, 180, 270}, sign = ±1, by LM from ``starts`` uniform random points of the
  search box each (multi-start: on the paper's data 70 % of uniform starts reach the global
  basin, see ``benchmarks/RESULTS.md``), and for the declared convention also from the full
  fit, so it is never worse than the fit itself. The pen's search box is kept, so
  conventions whose zeros differ by 180° (the pen offset turned half round) are told apart
  by it.

All stage-1 refits (n leave-one-out + 8 × starts + 1) are one batch of
:func:`~handeye_jax.optim.batched.levenberg_marquardt_batch`, the n stage-2 refits another.
"""

from __future__ import annotations

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from . import _xla
from .losses import AbstractLoss, LossObjective
from .models import AbstractCorrection, AbstractModel
from .objective import Stage1Objective, Stage2Objective, chain_points, fitness, norms
from .observations import Observations
from .optim.batched import levenberg_marquardt_batch

#: The hand-angle conventions (zero deg, sign) the convention check tries.
CONVENTIONS: tuple[tuple[float, int], ...] = tuple(
    (zero, sign) for sign in (1, -1) for zero in (0.0, 90.0, 180.0, 270.0)
)


@dataclass(frozen=True)
class Refits:
    """Outcome of :func:`refits`; lengths in mm, one row per landmark or convention.

    Attributes:
        loo1_image_vs_tablet, loo1_hand: the held-out error lengths of stage 1 at each
            left-out landmark.
        loo2_image_vs_tablet, loo2_hand: the same for the pipeline (stage 1 + stage 2).
        convention_F: the paper's F1st of the best refit under each of :data:`CONVENTIONS`.
        convention_params: the best refit's stage-1 parameters per convention, ``(8, d)``.
        declared_params, declared_F: every multi-start refit under the declared convention
            (the last one started from the fit) and its F1st: the local optima of stage 1.
        errors1, jacobian1, errors2, jacobian2: each stage's stacked error vectors at the
            full fit and their Jacobian (see :mod:`handeye_jax.identifiability`).
    """

    loo1_image_vs_tablet: np.ndarray
    loo1_hand: np.ndarray
    loo2_image_vs_tablet: np.ndarray
    loo2_hand: np.ndarray
    convention_F: np.ndarray
    convention_params: np.ndarray
    declared_params: np.ndarray
    declared_F: np.ndarray
    errors1: np.ndarray
    jacobian1: np.ndarray
    errors2: np.ndarray
    jacobian2: np.ndarray


def _with_convention(obs: Observations, zero_deg, sign) -> Observations:
    rig = eqx.tree_at(
        lambda r: (r.angle_zero_deg, r.angle_sign), obs.rig, (jnp.asarray(zero_deg), sign * 1.0)
    )
    return eqx.tree_at(lambda o: o.rig, obs, rig)


def _flat(errors) -> Float[Array, " r"]:
    return jnp.concatenate([errors.image_vs_tablet.reshape(-1), errors.hand.reshape(-1)])


def _two_jacobians(objective: LossObjective, x):
    """LM residuals and the raw error vectors at ``x``, each with its Jacobian, and the error
    vectors themselves: one forward-mode pass, and one trace of the transform chain."""

    def f(x):
        errors = objective.errors(x)
        out = (objective.residuals_of(errors), _flat(errors))
        return out, (out, errors)

    (J_r, J_e), ((r, e), errors) = jax.jacfwd(f, has_aux=True)(x)
    return r, J_r, e, J_e, errors


# jax.jit rather than eqx.filter_jit: these are called once per LM iteration, and jax.jit's
# dispatch is the cheaper one (every argument but the classes is a pytree of arrays).
@_xla.fast_compile(jit=jax.jit, llvm_opt_level=1, static_argnums=0)
def _stage1_batch(model_cls, obs, loss, zero, sign, weights, X):
    """Per problem: LM residuals and Jacobian, error vectors and Jacobian, error lengths and
    the paper's F1st at ``X``."""

    def one(zero_deg, sgn, w, x):
        base = Stage1Objective(model_cls, _with_convention(obs, zero_deg, sgn))
        r, J_r, e, J_e, errors = _two_jacobians(LossObjective(base, loss, w), x)
        return r, J_r, e, J_e, norms(errors), fitness(errors)[0]

    return jax.vmap(one)(zero, sign, weights, X)


@_xla.fast_compile(jit=jax.jit, llvm_opt_level=1, static_argnums=(0, 1))
def _stage2_batch(model_cls, correction_cls, obs, loss, X1, weights, X2):
    """Per problem: stage 2 on the points of stage-1 parameters ``X1``; as above."""

    def one(x1, w, x2):
        points = chain_points(model_cls.from_vector(x1), obs)
        base = Stage2Objective(correction_cls, points, obs.centre_index)
        r, J_r, e, J_e, errors = _two_jacobians(LossObjective(base, loss, w), x2)
        return r, J_r, e, J_e, norms(errors)

    return jax.vmap(one)(X1, weights, X2)


def refits(
    model_cls: type[AbstractModel],
    correction_cls: type[AbstractCorrection],
    obs: Observations,
    loss: AbstractLoss,
    x1: Float[Array, " d1"],
    x2: Float[Array, " d2"],
    bounds1: tuple[np.ndarray, np.ndarray],
    bounds2: tuple[np.ndarray, np.ndarray],
    seed: int,
    starts: int,
    max_steps: int,
) -> Refits:
    """Leave-one-out refits of both stages and the convention refits of stage 1.

    Args:
        model_cls, correction_cls: the stage-1 model and the stage-2 correction classes.
        obs: the observations, with the dataset's declared convention.
        loss: the loss the calibration used.
        x1, x2: the full fit's stage-1 and stage-2 parameters.
        bounds1, bounds2: each stage's search box ``(lower, upper)``.
        seed: seed of the convention multi-starts' uniform draws (NumPy's PCG64).
        starts: random LM starts per convention.
        max_steps: most LM iterations of every refit.
    """
    x1, x2 = np.asarray(x1, float), np.asarray(x2, float)
    n, d1 = obs.n_landmarks, x1.shape[0]
    n_conv = len(CONVENTIONS)
    lo1, hi1 = (np.asarray(b, float) for b in bounds1)
    zero = np.array([c[0] for c in CONVENTIONS])
    sign = np.array([float(c[1]) for c in CONVENTIONS])
    declared = int(np.argmax((zero == float(obs.rig.angle_zero_deg))
                             & (sign == float(obs.rig.angle_sign))))  # fmt: skip

    # Problems: n leave-one-out, then `starts` per convention, then the declared one from x1.
    leave_out = 1.0 - np.eye(n)
    conv_of = np.concatenate([np.repeat(np.arange(n_conv), starts), [declared]])
    x_random = np.random.default_rng(seed).uniform(lo1, hi1, size=(n_conv * starts, d1))
    # NumPy arrays throughout: the jitted batches take them as they are, while jnp.asarray
    # would compile a small program per shape.
    all_zero = np.concatenate([np.full(n, float(obs.rig.angle_zero_deg)), zero[conv_of]])
    all_sign = np.concatenate([np.full(n, float(obs.rig.angle_sign)), sign[conv_of]])
    all_w = np.concatenate([leave_out, np.ones((conv_of.shape[0], n))])
    all_x0 = np.concatenate([np.broadcast_to(x1, (n, d1)), x_random, x1[None]])

    def stage1(X):
        return _stage1_batch(model_cls, obs, loss, all_zero, all_sign, all_w, np.asarray(X))

    xs, _ = levenberg_marquardt_batch(lambda X: stage1(X)[:2], all_x0, lo1, hi1,
                                      max_steps=max_steps)  # fmt: skip
    # The last problem (declared convention, all landmarks) evaluated at the fit itself gives
    # the fit's error vectors and Jacobian from the same compiled program.
    at_fit = np.concatenate([xs[:-1], x1[None]])
    _, _, e1, J1, (n1, n2), F = (jax.tree.map(np.asarray, v) for v in stage1(at_fit))
    e1, J1 = e1[-1], J1[-1]
    F = F.copy()
    F[-1] = min(F[-1], float(np.asarray(stage1(xs)[5])[-1]))
    F_conv = np.where(np.isfinite(F[n:]), F[n:], np.inf)
    best = np.array([np.flatnonzero(conv_of == c)[np.argmin(F_conv[conv_of == c])]
                     for c in range(n_conv)])  # fmt: skip

    X1, W = xs[:n], leave_out

    def stage2(X, X1=X1):
        return _stage2_batch(model_cls, correction_cls, obs, loss, X1, W, np.asarray(X))

    x2s, _ = levenberg_marquardt_batch(lambda X: stage2(X)[:2], np.broadcast_to(x2, (n, x2.size)),
                                       *bounds2, max_steps=max_steps)  # fmt: skip
    m1, m2 = (np.asarray(v) for v in stage2(x2s)[4])
    # Row 0 at the full fit (x1, x2) gives stage 2's error vectors and Jacobian there.
    x2_fit = np.concatenate([x2[None], x2s[1:]])
    _, _, e2, J2, _ = stage2(x2_fit, np.concatenate([x1[None], xs[1:n]]))
    e2, J2 = np.asarray(e2)[0], np.asarray(J2)[0]
    mine = n + np.flatnonzero(conv_of == declared)
    diag = np.arange(n)
    return Refits(
        loo1_image_vs_tablet=n1[diag, diag],
        loo1_hand=n2[diag, diag],
        loo2_image_vs_tablet=m1[diag, diag],
        loo2_hand=m2[diag, diag],
        convention_F=F_conv[best],
        convention_params=xs[n:][best],
        declared_params=xs[mine],
        declared_F=np.where(np.isfinite(F[mine]), F[mine], np.inf),
        errors1=e1,
        jacobian1=J1,
        errors2=e2,
        jacobian2=J2,
    )
