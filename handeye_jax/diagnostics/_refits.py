"""Batched refits for the diagnostics: leave-one-out for both stages, and the hand-angle
conventions, with two small compiled programs (batched residuals and Jacobians per stage).

Every refit works on the fit's free parameters, with its prior if it has one: the stage
objectives come in as built for the fit (:class:`~handeye_jax.Stage1Objective`,
:class:`~handeye_jax.Stage2Objective`, maybe inside a :class:`~handeye_jax.PriorObjective`).

* **Leave-one-out, stage 1.** For each landmark m, Levenberg–Marquardt from the full optimum
  on the stage-1 objective with landmark m's weight set to 0; the held-out error is the refit
  model's error at landmark m. That is n refits of n landmarks each, O(n²): above
  :data:`EXACT_LOO_LANDMARKS` landmarks each refit is instead one Newton step from the full
  fit, from every landmark's gradient and Hessian there (O(n); :func:`one_step_loo`), and
  only the few landmarks that step moves far are refitted by LM (:data:`LOO_REFITS`).
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
  by it. Above :data:`REFIT_LANDMARKS` landmarks these refits search on that many, spread
  over the touch order (their cost stays bounded), and their F is then that of all landmarks.

Up to :data:`EXACT_LOO_LANDMARKS` landmarks, all stage-1 refits (n leave-one-out + 8 × starts
+ 1) are one batch of :func:`~handeye_jax.optim.minimise_batch`, the n
stage-2 refits another.
"""

from __future__ import annotations

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core import Stages
from .._jax import fast_compile
from ..calibration import CONVENTIONS, convention_index, uniform_starts
from ..optim import Box, LevenbergMarquardt, minimise_batch
from ..problem import (
    AbstractLoss,
    AbstractObjective,
    LossObjective,
    StageErrors,
    chain_points,
    data_objective,
    errors_of,
    fitness,
    landmark_terms,
    norms,
    spread_landmarks,
    touch_groups,
)

#: Up to this many landmarks, leave-one-out refits every stage without each landmark (O(n²));
#: above, it is one Newton step from the fit per landmark (O(n)).
EXACT_LOO_LANDMARKS = 64
#: Above this many landmarks the convention refits search on this many (see the docstring).
REFIT_LANDMARKS = 64
#: With the one-step leave-one-out, the landmarks whose error vectors the step moves by more
#: than the fit's RMS error length are refitted exactly instead, at most this many (largest
#: moves first): O(this · n).
LOO_REFITS = 16


@dataclass(frozen=True)
class RefitBudget:
    """How much the refits of :func:`refits` may search, and the seed of their draws.

    Attributes:
        seed: seed of the convention multi-starts' uniform draws (NumPy's PCG64).
        starts: random LM starts per convention, at least 1.
        max_steps: most LM iterations of every refit, at least 1.
        exact_loo_landmarks: up to this many landmarks leave-one-out refits exactly, above it
            takes one Newton step (:func:`one_step_loo`); at most ``refit_landmarks``.
        refit_landmarks: above this many landmarks the convention refits search on this many;
            at least 1.
    """

    seed: int
    starts: int
    max_steps: int
    exact_loo_landmarks: int = EXACT_LOO_LANDMARKS
    refit_landmarks: int = REFIT_LANDMARKS

    def __post_init__(self) -> None:
        # exact_loo_landmarks = 0 is allowed: one Newton step for every dataset.
        for name, least in (("starts", 1), ("max_steps", 1), ("exact_loo_landmarks", 0),
                            ("refit_landmarks", 1)):  # fmt: skip
            if not getattr(self, name) >= least:
                raise ValueError(f"{name}: must be at least {least} (got {getattr(self, name)})")
        if self.exact_loo_landmarks > self.refit_landmarks:
            raise ValueError(
                f"exact_loo_landmarks: must not exceed refit_landmarks "
                f"({self.exact_loo_landmarks} > {self.refit_landmarks})"
            )


@dataclass(frozen=True)
class _Pair:
    """Both stages as the refits take them: objectives without the loss (a prior kept), the
    loss, the fit's free parameters and each stage's box."""

    stage1: AbstractObjective
    stage2: AbstractObjective
    loss: AbstractLoss
    x1: np.ndarray
    x2: np.ndarray
    box1: Box
    box2: Box
    convention_starts: np.ndarray | None = None
    lm_box1: Box | None = None


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
            full fit and their Jacobian (see :mod:`handeye_jax.problem._linearise`).
        loo_method: how leave-one-out was computed, in words.
        refit_landmarks: how many landmarks the convention refits searched on.
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
    loo_method: str = "exact: LM refits without each landmark"
    refit_landmarks: int = 0


def _with_convention(objective: AbstractObjective, zero_deg, sign) -> AbstractObjective:
    """A stage-1 objective (its wrappers kept) under another hand-angle convention."""
    return eqx.tree_at(
        lambda o: (data_objective(o).obs.rig.angle_zero_deg, data_objective(o).obs.rig.angle_sign),
        objective,
        (jnp.asarray(zero_deg, dtype=float), sign * 1.0),
    )


def _stage2_at(stage1: AbstractObjective, stage2: AbstractObjective, x1) -> AbstractObjective:
    """``stage2`` (its wrappers kept) on the chain points of stage 1's parameters ``x1``."""
    inner = data_objective(stage1)
    points = chain_points(inner.model(x1), inner.obs)
    return eqx.tree_at(lambda o: data_objective(o).points, stage2, points)


def _lm(max_steps: int) -> LevenbergMarquardt:
    # The batch's rule: stop once no problem's cost fell by a fraction 1e-10 for 10 iterations.
    return LevenbergMarquardt(rtol=1e-10, atol=0.0, max_steps=max_steps)


def _obs(stage1: AbstractObjective):
    return data_objective(stage1).obs


def _flat(errors) -> Float[Array, " r"]:
    return jnp.concatenate([errors.image_vs_tablet.reshape(-1), errors.hand.reshape(-1)])


def _two_jacobians(objective: LossObjective, x):
    """LM residuals and the raw error vectors at ``x``, each with its Jacobian, and the error
    vectors themselves: one forward-mode pass, and one trace of the transform chain."""

    def f(x):
        blocks = objective.blocks(x)
        if "f1" in blocks:  # the paper's blocks, or a loss's: their error vectors are the data's
            errors = StageErrors(image_vs_tablet=blocks["f1"].errors, hand=blocks["f2"].errors)
        else:  # a noise model's whitened blocks: the paper's errors apart
            errors = errors_of(objective, x)
        out = (jnp.concatenate([b.residuals() for b in blocks.values()]), _flat(errors))
        return out, (out, errors)

    (J_r, J_e), ((r, e), errors) = jax.jacfwd(f, has_aux=True)(x)
    return r, J_r, e, J_e, errors


# jax.jit rather than eqx.filter_jit: these are called once per LM iteration, and jax.jit's
# dispatch is the cheaper one (every argument is a pytree of arrays with static metadata).
@fast_compile(jit=jax.jit, llvm_opt_level=1)
def _stage1_batch(stage1, loss, zero, sign, weights, X):
    """Per problem: LM residuals and Jacobian, error vectors and Jacobian, error lengths and
    the paper's F1st at ``X``."""

    def one(zero_deg, sgn, w, x):
        objective = LossObjective(_with_convention(stage1, zero_deg, sgn), loss, w)
        r, J_r, e, J_e, errors = _two_jacobians(objective, x)
        return r, J_r, e, J_e, norms(errors), fitness(errors)[0]

    return jax.vmap(one)(zero, sign, weights, X)


@fast_compile(jit=jax.jit, llvm_opt_level=1)
def _stage2_batch(stage1, stage2, loss, X1, weights, X2):
    """Per problem: stage 2 on the points of stage-1 parameters ``X1``; as above."""

    def one(x1, w, x2):
        objective = LossObjective(_stage2_at(stage1, stage2, x1), loss, w)
        r, J_r, e, J_e, errors = _two_jacobians(objective, x2)
        return r, J_r, e, J_e, norms(errors)

    return jax.vmap(one)(X1, weights, X2)


@fast_compile(jit=jax.jit)
def _stage1_F(stage1, zero, sign, X):
    """The paper's F1st of each problem at ``X``."""

    def one(zero_deg, sgn, x):
        return fitness(errors_of(_with_convention(stage1, zero_deg, sgn), x))[0]

    return jax.vmap(one)(zero, sign, X)


@fast_compile(jit=jax.jit)
def _loo_derivatives(stage1, stage2, loss, x1, x2):
    """At the full fit: each landmark's loss term's gradient and Hessian, for stage 1 in
    ``x1`` and for stage 2 in ``(x1, x2)`` (its points move with ``x1``), each stage's error
    vectors and their Jacobian, and F1st. Forward mode throughout: O(n·d²), no n × n array.
    A prior's block is left out of the terms: it belongs to no landmark."""
    d1 = x1.shape[0]
    ones = jnp.ones(_obs(stage1).n_landmarks)

    def stage1_terms(x1):
        objective = LossObjective(stage1, loss, ones)
        return landmark_terms(objective, x1), _flat(errors_of(objective, x1))

    def stage2_terms(x):
        objective = LossObjective(_stage2_at(stage1, stage2, x[:d1]), loss, ones)
        return landmark_terms(objective, x[d1:]), _flat(errors_of(objective, x[d1:]))

    def derivatives(f, x):
        def both(x):
            out = f(x)
            return out, out

        (g, E), (_, e) = jax.jacfwd(both, has_aux=True)(x)
        H = jax.jacfwd(jax.jacfwd(lambda y: f(y)[0]))(x)
        return g, H, e, E

    F1 = fitness(errors_of(stage1, x1))[0]
    return derivatives(stage1_terms, x1), derivatives(stage2_terms, jnp.concatenate([x1, x2])), F1


def _per_landmark(v: np.ndarray, n: int) -> np.ndarray:
    """Rows of a stacked ``(4n, …)`` error vector or Jacobian grouped by landmark:
    ``(n, 4, …)``, each landmark's image-vs-tablet x, y then hand x, y."""
    return np.moveaxis(v.reshape(2, n, 2, *v.shape[1:]), 0, 1).reshape(n, 4, *v.shape[1:])


def _solve_each(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``H[m]⁺ g[m]`` for a stack of symmetric ``(n, d, d)``, in parameters scaled to unit
    curvature (mm, deg and scale factors compared). Directions of non-positive curvature, or
    of one below 1e-14 of the largest (the data do not determine them), are left out."""
    scale = np.sqrt(np.abs(np.diagonal(H.sum(axis=0)))) + 1e-300
    w, V = np.linalg.eigh(H / np.outer(scale, scale)[None])
    keep = w > 1e-14 * w.max(axis=1, keepdims=True)
    coef = np.einsum("mji,mj->mi", V, g / scale) * np.where(keep, 1.0 / np.where(keep, w, 1.0), 0)
    return np.einsum("mij,mj->mi", V, coef) / scale


def one_step_loo(
    stage1: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    stage2: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    x1: np.ndarray,
    x2: np.ndarray,
    *,
    bounds1: tuple[np.ndarray, np.ndarray],
    bounds2: tuple[np.ndarray, np.ndarray],
    groups: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Leave-one-out of both stages by one Newton step from the full fit, in O(n).

    With ``t_m`` group m's terms of a stage's objective (a group: a touch's rows, a landmark
    for the paper's single capture), ``g_m``, ``H_m`` their gradient and Hessian at the fit
    and ``H = Σ H_m``: the fit is stationary, so without group m the gradient is ``−g_m`` and
    Newton's step is ``δ1 = (H − H_m)⁺ g_m``. Stage 2 without m is refitted on the points of
    ``x1 + δ1``: ``δ2 = (H₂₂ − H₂₂,m)⁺ (g₂,m − (H₂₁ − H₂₁,m)·δ1)`` (blocks of its Hessian in
    ``(x1, x2)``). Each refit is kept in its box. The held-out errors are group m's rows'
    error vectors, linearised, there (their lengths averaged over its rows). The sums over
    rows are formed once; each group then costs one ``d × d`` solve.

    Args:
        stage1: ``(g, H, e, E)``: stage 1's per-row gradients ``(n, d1)`` and Hessians
            ``(n, d1, d1)`` of its terms, its error vectors ``(4n,)`` (mm) and their Jacobian
            ``(4n, d1)``.
        stage2: the same for stage 2, in the joint parameters ``(x1, x2)`` (``d1 + d2``).
        x1, x2: the full fit.
        bounds1, bounds2: each stage's box ``(lower, upper)``.
        groups: each row's group, ``0 … k−1`` (default: each row its own).

    Returns:
        The held-out error lengths (mm) of stage 1's two terms and of the pipeline's, each
        ``(k,)``: ``(image_vs_tablet1, hand1, image_vs_tablet2, hand2)``, and how far each
        group's error vectors moved from the fit's (the largest of the four, mm): a large
        move says the quadratic model was stretched past where it holds.
    """
    g1, H1, e1, E1 = stage1
    g2, H2, e2, E2 = stage2
    n, d1 = g1.shape
    groups = np.arange(n) if groups is None else np.asarray(groups)
    k = int(groups.max()) + 1
    g1, H1, g2, H2 = (_group_sum(a, groups, k) for a in (g1, H1, g2, H2))
    d1_m = _solve_each(H1.sum(axis=0)[None] - H1, g1)
    d1_m = np.clip(x1 + d1_m, *bounds1) - x1
    H22, H21 = H2[:, d1:, d1:], H2[:, d1:, :d1]
    rhs = g2[:, d1:] - np.einsum("mij,mj->mi", H21.sum(axis=0)[None] - H21, d1_m)
    d2_m = _solve_each(H22.sum(axis=0)[None] - H22, rhs)
    d2_m = np.clip(x2 + d2_m, *bounds2) - x2
    # Each row moves with its group's step.
    shift1 = np.einsum("mki,mi->mk", _per_landmark(E1, n), d1_m[groups])
    step = np.concatenate([d1_m, d2_m], axis=1)[groups]
    shift2 = np.einsum("mki,mi->mk", _per_landmark(E2, n), step)
    held1, held2 = _per_landmark(e1, n) + shift1, _per_landmark(e2, n) + shift2
    lengths = tuple(_group_mean(np.linalg.norm(h[:, c : c + 2], axis=1), groups, k)
                    for h in (held1, held2) for c in (0, 2))  # fmt: skip
    moved = np.max([np.linalg.norm(v[:, c : c + 2], axis=1) for v in (shift1, shift2)
                    for c in (0, 2)], axis=0)  # fmt: skip
    moved_group = np.zeros(k)
    np.maximum.at(moved_group, groups, moved)
    return (*lengths, moved_group)


def _group_sum(a: np.ndarray, groups: np.ndarray, k: int) -> np.ndarray:
    """Rows of ``a`` summed per group: ``(k, …)``."""
    out = np.zeros((k, *a.shape[1:]))
    np.add.at(out, groups, a)
    return out


def _group_mean(a: np.ndarray, groups: np.ndarray, k: int) -> np.ndarray:
    """Rows of ``a`` averaged per group: ``(k,)``."""
    return _group_sum(a, groups, k) / np.bincount(groups, minlength=k)


def refits(
    stages: Stages,
    loss: AbstractLoss,
    budget: RefitBudget,
    *,
    convention_starts: np.ndarray | None = None,
) -> Refits:
    """Leave-one-out refits of both stages and the convention refits of stage 1.

    Args:
        stages: each stage as fitted (:class:`~handeye_jax.calibration.FittedStage`: its
            objective on its free parameters, a prior kept and the loss not, with the
            dataset's declared convention; its optimum ``x``; its ``space``'s box).
        loss: the loss the calibration used.
        budget: the seed, starts, LM iterations and landmark limits of the refits
            (:class:`RefitBudget`).
        convention_starts: one more start per convention, ``(8, d)`` (a row of NaN: none),
            e.g. the closed-form estimate under each; the stage-1 refits' box is widened to
            hold them (the uniform starts are still drawn from the fit's box).
    """
    seed, starts, max_steps = budget.seed, budget.starts, budget.max_steps
    one, two = stages.stage1, stages.stage2
    box1 = lm_box1 = one.space.box
    if convention_starts is not None:
        ok = np.isfinite(convention_starts).all(axis=1)
        rows = convention_starts[ok]
        lm_box1 = Box(np.minimum(box1.lower, rows.min(axis=0, initial=np.inf)),
                      np.maximum(box1.upper, rows.max(axis=0, initial=-np.inf)))  # fmt: skip
    pair = _Pair(one.objective, two.objective, loss, np.asarray(one.x, float),
                 np.asarray(two.x, float), box1, two.space.box, convention_starts,
                 lm_box1)  # fmt: skip
    if _obs(pair.stage1).n_landmarks > budget.exact_loo_landmarks:
        return _refits_one_step(pair, seed, starts, max_steps, budget.refit_landmarks)
    return _refits_exact(pair, seed, starts, max_steps)


def _convention_problems(obs, x1, box: Box, seed, starts, extra: np.ndarray | None = None):
    """Each convention's zero and sign, and the LM starts: ``starts`` uniform draws per
    convention (the fit's own refits drew the declared convention's, the same points), the
    ``extra`` start of each convention that has one, then the declared convention from the
    fit (last)."""
    n_conv = len(CONVENTIONS)
    zero = np.array([c[0] for c in CONVENTIONS])
    sign = np.array([float(c[1]) for c in CONVENTIONS])
    declared = convention_index(float(obs.rig.angle_zero_deg), float(obs.rig.angle_sign))
    conv_of = np.repeat(np.arange(n_conv), starts)
    x0 = uniform_starts(seed, box, n_conv * starts)
    if extra is not None:
        ok = np.flatnonzero(np.isfinite(extra).all(axis=1))
        conv_of, x0 = np.concatenate([conv_of, ok]), np.concatenate([x0, extra[ok]])
    return zero, sign, declared, np.concatenate([conv_of, [declared]]), \
        np.concatenate([x0, x1[None]])  # fmt: skip


def _best_per_convention(F_conv, conv_of):
    return np.array([np.flatnonzero(conv_of == c)[np.argmin(F_conv[conv_of == c])]
                     for c in range(len(CONVENTIONS))])  # fmt: skip


def _refits_one_step(p: _Pair, seed, starts, max_steps, refit_landmarks) -> Refits:
    """:func:`refits` with the one-step leave-one-out, in O(n)."""
    stage1, stage2, loss, x1, x2, bounds1, bounds2 = (p.stage1, p.stage2, p.loss, p.x1, p.x2,
                                                     p.box1, p.box2)  # fmt: skip
    obs = _obs(stage1)
    n = obs.n_landmarks
    zero, sign, declared, conv_of, x0 = _convention_problems(obs, x1, bounds1, seed, starts,
                                                             p.convention_starts)  # fmt: skip
    bounds1 = bounds1 if p.lm_box1 is None else p.lm_box1
    searched = stage1
    if n > refit_landmarks:
        # Its wrappers subset too (a noise model's whiteners are per landmark).
        searched = stage1.on_landmarks(np.asarray(spread_landmarks(n, refit_landmarks)))
    m = _obs(searched).n_landmarks
    w = np.ones((conv_of.shape[0], m))

    def batch1(X):
        out = _stage1_batch(searched, loss, zero[conv_of], sign[conv_of], w, np.asarray(X))
        return out[:2]

    xs = minimise_batch(batch1, _lm(max_steps), bounds1, x0).x
    F = np.asarray(_stage1_F(stage1, zero[conv_of], sign[conv_of], xs)).copy()
    # At the fit, on all landmarks: its F (the declared refit from it is never worse), and
    # the derivatives for the leave-one-out and the identifiability analysis.
    d1 = x1.shape[0]
    one, two, F_fit = jax.tree.map(np.asarray, _loo_derivatives(stage1, stage2, loss, x1, x2))
    if not F[-1] <= F_fit:
        xs[-1], F[-1] = x1, F_fit
    box1, box2 = (bounds1.lower, bounds1.upper), (bounds2.lower, bounds2.upper)
    groups = touch_groups(obs)
    *loo, moved = one_step_loo(one, two, x1, x2, bounds1=box1, bounds2=box2, groups=groups)
    # A shift–tilt valley can stretch Newton's step far past where its quadratic model holds
    # (tens of mm where a refit moves the held-out error by hundredths): refit those exactly.
    rms = float(np.sqrt(np.mean(np.sum(_per_landmark(one[2], n).reshape(n, 2, 2) ** 2, -1))))
    far = np.argsort(-moved, kind="stable")[:LOO_REFITS]
    far = np.sort(far[moved[far] > rms])
    if far.size:
        exact = _exact_loo_at(p, far, groups, max_steps)
        for held, refit in zip(loo, exact, strict=True):
            held[far] = refit
    F_conv = np.where(np.isfinite(F), F, np.inf)
    best = _best_per_convention(F_conv, conv_of)
    mine = np.flatnonzero(conv_of == declared)
    return Refits(
        loo1_image_vs_tablet=loo[0],
        loo1_hand=loo[1],
        loo2_image_vs_tablet=loo[2],
        loo2_hand=loo[3],
        convention_F=F_conv[best],
        convention_params=xs[best],
        declared_params=xs[mine],
        declared_F=F_conv[mine],
        errors1=one[2],
        jacobian1=one[3],
        errors2=two[2],
        jacobian2=two[3][:, d1:],
        loo_method="one Newton step from the full fit without each touch"
        + (f", exact LM refits for the {far.size} it moved most" if far.size else "")
        + f" (exact LM refits for all up to {EXACT_LOO_LANDMARKS} rows)",
        refit_landmarks=m,
    )


def _exact_loo_at(p: _Pair, which_groups, groups: np.ndarray, max_steps) -> tuple[np.ndarray, ...]:
    """Leave-one-out by LM refits of both stages for ``which_groups`` only (as the exact
    path does for all), batched in :data:`LOO_REFITS` problems; O(LOO_REFITS · n) a step.
    Returns each group's held-out error lengths, averaged over its rows."""
    stage1, stage2, loss, x1, x2, bounds1, bounds2 = (p.stage1, p.stage2, p.loss, p.x1, p.x2,
                                                     p.box1, p.box2)  # fmt: skip
    obs = _obs(stage1)
    k = len(which_groups)
    which = np.concatenate([which_groups, np.full(LOO_REFITS - k, which_groups[-1])])
    W = (groups[None, :] != which[:, None]).astype(float)
    zero = np.full(LOO_REFITS, float(obs.rig.angle_zero_deg))
    sign = np.full(LOO_REFITS, float(obs.rig.angle_sign))

    def batch1(X):
        return _stage1_batch(stage1, loss, zero, sign, W, np.asarray(X))

    lm = _lm(max_steps)
    X1 = minimise_batch(lambda X: batch1(X)[:2], lm, bounds1, np.tile(x1, (LOO_REFITS, 1))).x

    def batch2(X):
        return _stage2_batch(stage1, stage2, loss, X1, W, np.asarray(X))

    X2 = minimise_batch(lambda X: batch2(X)[:2], lm, bounds2, np.tile(x2, (LOO_REFITS, 1))).x
    held = (*batch1(X1)[4], *batch2(X2)[4])
    return tuple(_held_out(np.asarray(v)[:k], which_groups, groups) for v in held)


def _held_out(lengths: np.ndarray, which_groups: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Problem i's error lengths at the rows of group ``which_groups[i]`` it left out,
    averaged: ``(len(which_groups),)``."""
    mask = groups[None, :] == np.asarray(which_groups)[:, None]
    return np.sum(np.where(mask, lengths, 0.0), axis=1) / np.sum(mask, axis=1)


def _stage2_loo(p: _Pair, lm: LevenbergMarquardt, X1: np.ndarray, W: np.ndarray):
    """Stage 2 refitted on each leave-one-out stage 1 (``X1``, weights ``W``): the held-out
    error lengths ``(m1, m2)``, and stage 2's error vectors and Jacobian at the full fit."""
    k, x2 = X1.shape[0], p.x2

    def batch2(X, X1=X1):
        return _stage2_batch(p.stage1, p.stage2, p.loss, X1, W, np.asarray(X))

    x2s = minimise_batch(lambda X: batch2(X)[:2], lm, p.box2, np.broadcast_to(x2, (k, x2.size))).x
    m1, m2 = (np.asarray(v) for v in batch2(x2s)[4])
    # Problem 0 at the full fit (x1, x2) gives stage 2's error vectors and Jacobian there.
    x2_fit = np.concatenate([x2[None], x2s[1:]])
    _, _, e2, J2, _ = batch2(x2_fit, np.concatenate([p.x1[None], X1[1:]]))
    return m1, m2, np.asarray(e2)[0], np.asarray(J2)[0]


def _refits_exact(p: _Pair, seed, starts, max_steps) -> Refits:
    """:func:`refits` with leave-one-out by exact refits, O(n²)."""
    stage1, loss, x1, bounds1 = p.stage1, p.loss, p.x1, p.box1
    obs = _obs(stage1)
    n, d1 = obs.n_landmarks, x1.shape[0]
    zero, sign, declared, conv_of, x0 = _convention_problems(obs, x1, bounds1, seed, starts,
                                                             p.convention_starts)  # fmt: skip
    bounds1 = bounds1 if p.lm_box1 is None else p.lm_box1

    # Problems: k leave-one-out (a touch's rows at a time), then `starts` per convention, then
    # the declared one from x1.
    groups = touch_groups(obs)
    k = int(groups.max()) + 1
    leave_out = (groups[None, :] != np.arange(k)[:, None]).astype(float)
    # NumPy arrays throughout: the jitted batches take them as they are, while jnp.asarray
    # would compile a small program per shape.
    all_zero = np.concatenate([np.full(k, float(obs.rig.angle_zero_deg)), zero[conv_of]])
    all_sign = np.concatenate([np.full(k, float(obs.rig.angle_sign)), sign[conv_of]])
    all_w = np.concatenate([leave_out, np.ones((conv_of.shape[0], n))])
    all_x0 = np.concatenate([np.broadcast_to(x1, (k, d1)), x0])

    def batch1(X):
        return _stage1_batch(stage1, loss, all_zero, all_sign, all_w, np.asarray(X))

    lm = _lm(max_steps)
    xs = minimise_batch(lambda X: batch1(X)[:2], lm, bounds1, all_x0).x
    # The last problem (declared convention, all landmarks) evaluated at the fit itself gives
    # the fit's error vectors and Jacobian from the same compiled program.
    at_fit = np.concatenate([xs[:-1], x1[None]])
    _, _, e1, J1, (n1, n2), F = (jax.tree.map(np.asarray, v) for v in batch1(at_fit))
    e1, J1 = e1[-1], J1[-1]
    F = F.copy()
    F[-1] = min(F[-1], float(np.asarray(batch1(xs)[5])[-1]))
    F_conv = np.where(np.isfinite(F[k:]), F[k:], np.inf)
    best = _best_per_convention(F_conv, conv_of)

    m1, m2, e2, J2 = _stage2_loo(p, lm, xs[:k], leave_out)
    mine = k + np.flatnonzero(conv_of == declared)
    each = np.arange(k)
    return Refits(
        loo1_image_vs_tablet=_held_out(n1[:k], each, groups),
        loo1_hand=_held_out(n2[:k], each, groups),
        loo2_image_vs_tablet=_held_out(m1, each, groups),
        loo2_hand=_held_out(m2, each, groups),
        convention_F=F_conv[best],
        convention_params=xs[k:][best],
        declared_params=xs[mine],
        declared_F=np.where(np.isfinite(F[mine]), F[mine], np.inf),
        errors1=e1,
        jacobian1=J1,
        errors2=e2,
        jacobian2=J2,
    )
