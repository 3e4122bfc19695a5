"""Batched refits for the diagnostics: leave-one-out for both stages, and the hand-angle
conventions, as one compiled program.

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

All stage-1 refits (n leave-one-out + 8 × starts + 1) share one vmapped LM.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .identifiability import error_jacobian
from .losses import AbstractLoss, LossObjective
from .models import AbstractCorrection, AbstractModel
from .objective import Stage1Objective, Stage2Objective, chain_points, fitness, norms
from .observations import Observations
from .optim.batched import levenberg_marquardt_steps

#: The hand-angle conventions (zero deg, sign) the convention check tries.
CONVENTIONS: tuple[tuple[float, int], ...] = tuple(
    (zero, sign) for sign in (1, -1) for zero in (0.0, 90.0, 180.0, 270.0)
)


class Refits(eqx.Module):
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

    loo1_image_vs_tablet: Float[Array, " n"]
    loo1_hand: Float[Array, " n"]
    loo2_image_vs_tablet: Float[Array, " n"]
    loo2_hand: Float[Array, " n"]
    convention_F: Float[Array, " 8"]
    convention_params: Float[Array, "8 d"]
    declared_params: Float[Array, "k d"]
    declared_F: Float[Array, " k"]
    errors1: Float[Array, " r"]
    jacobian1: Float[Array, "r d1"]
    errors2: Float[Array, " r"]
    jacobian2: Float[Array, "r d2"]


def _with_convention(obs: Observations, zero_deg, sign) -> Observations:
    rig = eqx.tree_at(
        lambda r: (r.angle_zero_deg, r.angle_sign), obs.rig, (jnp.asarray(zero_deg), sign * 1.0)
    )
    return eqx.tree_at(lambda o: o.rig, obs, rig)


@eqx.filter_jit
def refits(
    model_cls: type[AbstractModel],
    correction_cls: type[AbstractCorrection],
    obs: Observations,
    loss: AbstractLoss,
    x1: Float[Array, " d1"],
    x2: Float[Array, " d2"],
    bounds1: tuple[Float[Array, " d1"], Float[Array, " d1"]],
    bounds2: tuple[Float[Array, " d2"], Float[Array, " d2"]],
    key: PRNGKeyArray,
    starts: int,
    steps: int,
) -> Refits:
    """Leave-one-out refits of both stages and the convention refits of stage 1.

    Args:
        model_cls, correction_cls: the stage-1 model and the stage-2 correction classes.
        obs: the observations, with the dataset's declared convention.
        loss: the loss the calibration used.
        x1, x2: the full fit's stage-1 and stage-2 parameters.
        bounds1, bounds2: each stage's search box ``(lower, upper)``.
        key: PRNG key for the convention multi-starts.
        starts: random LM starts per convention, static.
        steps: LM iterations of every refit, static.
    """
    n, d1 = obs.n_landmarks, x1.shape[0]
    n_conv = len(CONVENTIONS)
    lo1, hi1 = bounds1
    lo2, hi2 = bounds2
    zero = jnp.array([c[0] for c in CONVENTIONS])
    sign = jnp.array([float(c[1]) for c in CONVENTIONS])
    declared = jnp.argmax((zero == obs.rig.angle_zero_deg) & (sign == obs.rig.angle_sign))

    # Problems: n leave-one-out, then `starts` per convention, then the declared one from x1.
    leave_out = 1.0 - jnp.eye(n)
    conv_of = jnp.concatenate([jnp.repeat(jnp.arange(n_conv), starts), declared[None]])
    x_random = jax.random.uniform(key, (n_conv * starts, d1), minval=lo1, maxval=hi1)
    all_zero = jnp.concatenate([jnp.full(n, obs.rig.angle_zero_deg), zero[conv_of]])
    all_sign = jnp.concatenate([jnp.full(n, obs.rig.angle_sign), sign[conv_of]])
    all_w = jnp.concatenate([leave_out, jnp.ones((conv_of.shape[0], n))])
    all_x0 = jnp.concatenate([jnp.broadcast_to(x1, (n, d1)), x_random, x1[None]])

    def lm1(zero_deg, sgn, weights, x0):
        obj = LossObjective(Stage1Objective(model_cls, _with_convention(obs, zero_deg, sgn)),
                            loss, weights)  # fmt: skip
        x, _ = levenberg_marquardt_steps(obj.residuals, x0, lo1, hi1, steps=steps)
        errors = obj.errors(x)
        return x, norms(errors), fitness(errors)[0]

    xs, (n1, n2), F = jax.vmap(lm1)(all_zero, all_sign, all_w, all_x0)

    F_conv = jnp.where(jnp.isfinite(F[n:]), F[n:], jnp.inf)
    best = jax.vmap(lambda c: jnp.argmin(jnp.where(conv_of == c, F_conv, jnp.inf)))(
        jnp.arange(n_conv)
    )

    def lm2(x1m, weights):
        points = chain_points(model_cls.from_vector(x1m), obs)
        obj = LossObjective(Stage2Objective(correction_cls, points, obs.centre_index), loss,
                            weights)  # fmt: skip
        x, _ = levenberg_marquardt_steps(obj.residuals, x2, lo2, hi2, steps=steps)
        return norms(obj.errors(x))

    m1, m2 = jax.vmap(lm2)(xs[:n], leave_out)
    points = chain_points(model_cls.from_vector(x1), obs)
    e1, J1 = error_jacobian(Stage1Objective(model_cls, obs), x1)
    e2, J2 = error_jacobian(Stage2Objective(correction_cls, points, obs.centre_index), x2)
    mine = n + jnp.nonzero(conv_of == declared, size=starts + 1)[0]
    diag = jnp.arange(n)
    return Refits(
        loo1_image_vs_tablet=n1[diag, diag],
        loo1_hand=n2[diag, diag],
        loo2_image_vs_tablet=m1[diag, diag],
        loo2_hand=m2[diag, diag],
        convention_F=F_conv[best],
        convention_params=xs[n:][best],
        declared_params=xs[mine],
        declared_F=jnp.where(jnp.isfinite(F[mine]), F[mine], jnp.inf),
        errors1=e1,
        jacobian1=J1,
        errors2=e2,
        jacobian2=J2,
    )
