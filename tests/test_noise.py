"""The noise model's scales, estimated from residuals whose noise is known: the image's and the
depth's apart where the views have a z (several captures with the hand's heights), one shared
scale where they do not (one capture, x-y only)."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import handeye_jax
from handeye_jax import (
    HTMModel,
    Rig,
    Scene,
    Stage1Objective,
    snake_grid_px,
    synthesize_dataset,
)
from handeye_jax.problem import (
    estimate_noise,
    get_noise_model,
    noise_objective,
    row_counts,
    std_dof,
)

TRUTH = dict(xc=-3.0, yc=35.0, alpha_c=-1.5, beta_c=2.0, gamma_c=4.0, xt=150.0, yt=40.0,
             alpha_t=2.0, beta_t=-8.0, gamma_t=-3.0, xp=4.0, yp=-25.0)  # fmt: skip
RIG = Rig(617.7, 617.7, 316.5, 242.3, [320.0, -70.0, 290.0], 0.0, 1.0)
POSES = [([320.0, -70.0, 290.0], 0.0), ([330.0, -80.0, 350.0], 15.0),
         ([310.0, -50.0, 390.0], -20.0)]  # fmt: skip
PAPER = get_noise_model("paper")  # image 0.1 px, depth 0.3 mm
DRAWS = 24
ROUNDS = 5  # the fit alternates LM and one step of the scales at most this often


@pytest.fixture(scope="module")
def clean():
    """Noise-free data on a 7 × 7 grid: one capture, and three with the hand's heights
    recorded (the pen's tip 7 mm below the flange)."""
    grid = snake_grid_px(tuple(np.linspace(400, 1040, 7)), tuple(np.linspace(150, 550, 7)))
    angles = np.linspace(0.0, 180.0, len(grid))
    with handeye_jax.float64():
        truth = HTMModel.from_dict(TRUTH)
        one = synthesize_dataset(truth, RIG, grid, angles)
        three = synthesize_dataset(truth, RIG, grid, angles, captures=POSES,
                                   scene=Scene(camera_z_mm=3.0, tablet_height_mm=120.0,
                                                 pen_z_mm=7.0))  # fmt: skip
    return truth, one, three


@eqx.filter_jit
def _gauss_newton(objective, x):
    r, J = objective.whitened(x), jax.jacfwd(objective.whitened)(x)
    return x - jnp.linalg.lstsq(J, r)[0]


def _fitted(objective, x):
    """The objective's optimum from near it (the noise is small: Gauss-Newton converges)."""
    for _ in range(3):
        x = _gauss_newton(objective, x)
    return x


def _scales(truth, ds, image_px: float, depth_mm: float, seed: int):
    """The scales estimated at the fit from the pictures given this noise, ``DRAWS`` times:
    (image variance px², depth variance mm², depth redundancy) per draw."""
    rng = np.random.default_rng(seed)
    out = []
    with handeye_jax.float64():
        theta = truth.to_vector()
        exact = ds.observations()  # a row per view: each picture's noise is its row's
        uv, d = np.asarray(exact.image_px), np.asarray(exact.depth_mm)
        for _ in range(DRAWS):
            obs = eqx.tree_at(lambda o: (o.image_px, o.depth_mm), exact,
                              (jnp.asarray(uv + rng.normal(0.0, image_px, uv.shape)),
                               jnp.asarray(d + rng.normal(0.0, depth_mm, d.shape))))
            noise, x = PAPER, jnp.asarray(theta)
            for _ in range(ROUNDS):  # as the fit alternates the optimum and the scales
                objective = noise_objective(Stage1Objective(HTMModel, obs), noise, truth, obs)
                x = _fitted(objective, x)
                found = estimate_noise(objective, x, noise, None, row_counts(obs))
                noise = found.noise
            image, depth = found.noise.picture_variances()
            red = found.depth_redundancy
            out.append((image, depth, np.nan if red is None else red))
    return np.array(out, dtype=float)


@pytest.mark.parametrize("image_px,depth_mm", [(0.05, 0.3), (0.2, 0.1)])
def test_image_and_depth_noise_are_estimated_apart_from_views_with_a_z(clean, image_px, depth_mm):
    """Rendered 2-px dots are found to 0.05 px while the depth stays at 0.3 mm: both σ are
    recovered (the mean of the draws' variances within 10 %), not one scale for both."""
    truth, _, three = clean
    got = _scales(truth, three, image_px, depth_mm, seed=1)
    assert np.all(got[:, 2] >= 2.0)  # the depth had a share of its own in every draw
    assert np.mean(got[:, 0]) == pytest.approx(image_px**2, rel=0.10)
    assert np.mean(got[:, 1]) == pytest.approx(depth_mm**2, rel=0.10)


def test_depth_noise_alone_is_not_taken_for_image_noise(clean):
    """The views' z offset is profiled under their covariances: its error, common to every
    row, no longer reaches their x-y as image noise (it did, as about 15 degrees of χ²)."""
    truth, _, three = clean
    got = _scales(truth, three, 0.0, 0.3, seed=3)
    assert np.all(got[:, 0] < 1e-3 * PAPER.image_sigma_px**2)
    assert np.mean(got[:, 1]) == pytest.approx(0.3**2, rel=0.10)


def test_views_without_a_z_keep_one_scale_for_the_image_and_the_depth(clean):
    """One capture, x-y only: the depth is a lateral lever on the image's error there, and the
    two cannot be told apart; the preset's ratio is kept and one scale estimated."""
    truth, one, _ = clean
    got = _scales(truth, one, 0.2, 0.6, seed=2)
    assert np.all(np.isnan(got[:, 2]))  # no depth share reported
    ratio = got[:, 1] / got[:, 0]
    np.testing.assert_allclose(ratio, PAPER.depth_sigma_mm**2 / PAPER.image_sigma_px**2)
    # Both σ doubled, so the one scale is about 4: each variance within 10 % on average.
    assert np.mean(got[:, 0]) == pytest.approx(0.2**2, rel=0.10)


def test_a_shared_scale_stays_shared_and_a_depth_scale_is_kept_apart():
    shared = PAPER.scaled(4.0, 2.0)
    assert shared.depth_scale is None
    assert shared.picture_variances() == pytest.approx((0.2**2, 0.6**2))
    apart = PAPER.scaled(0.25, 1.0, depth=1.0)
    assert apart.picture_variances() == pytest.approx((0.05**2, 0.3**2))
    again = apart.scaled(4.0)  # both variances times 4, the depth's own scale with them
    assert again.picture_variances() == pytest.approx((0.1**2, 0.6**2))
    with pytest.raises(ValueError, match="depth_scale"):
        type(PAPER)(depth_scale=float("nan"))


# -- each σ's degrees of freedom ---------------------------------------------------------------


def _fit_once(truth, ds, image_px: float, depth_mm: float, touch_mm: float, seed: int):
    """One noisy draw of ``ds`` (pictures, and the touches' hand positions), fitted with its
    scales estimated: the objective at the fit, the fit and the scales' fit."""
    rng = np.random.default_rng(seed)
    with handeye_jax.float64():
        exact = ds.observations()
        uv, d = np.asarray(exact.image_px), np.asarray(exact.depth_mm)
        hand = np.asarray(exact.hand_xy_mm)
        # A touch's error is one per touch, whichever of its rows repeats it.
        rows = (np.arange(len(hand)) if exact.touch_index is None
                else np.asarray(exact.touch_index))  # fmt: skip
        touch = rng.normal(0.0, touch_mm, (int(rows.max()) + 1, 2))
        obs = eqx.tree_at(lambda o: (o.image_px, o.depth_mm, o.hand_xy_mm), exact,
                          (jnp.asarray(uv + rng.normal(0.0, image_px, uv.shape)),
                           jnp.asarray(d + rng.normal(0.0, depth_mm, d.shape)),
                           jnp.asarray(hand + touch[rows])))
        noise, x = PAPER, jnp.asarray(truth.to_vector())
        for _ in range(ROUNDS):
            objective = noise_objective(Stage1Objective(HTMModel, obs), noise, truth, obs)
            x = _fitted(objective, x)
            found = estimate_noise(objective, x, noise, None, row_counts(obs))
            noise = found.noise
        objective = noise_objective(Stage1Objective(HTMModel, obs), noise, truth, obs)
    return objective, x, found


@pytest.mark.parametrize("which", ["one", "three"])
def test_each_sigma_has_the_degrees_of_freedom_of_the_scales_it_rests_on(clean, which):
    """Satterthwaite's count lies between the least of the scales' redundancies and their sum
    (a parameter one scale alone sets has that scale's: the paper's stage 2, below)."""
    truth, one, three = clean
    objective, x, fit = _fit_once(truth, one if which == "one" else three, 0.1, 0.3, 0.3, 5)
    reds = [fit.touch_redundancy]
    if fit.depth_redundancy is None:
        reds.append(fit.view_redundancy)
    else:
        reds += [fit.view_redundancy - fit.depth_redundancy, fit.depth_redundancy]
    assert len(reds) == (2 if which == "one" else 3)
    nu = std_dof(objective, x, fit)
    assert nu.shape == (12,) and np.all(np.isfinite(nu))
    assert np.all(nu >= min(reds) - 1e-9) and np.all(nu <= sum(reds) + 1e-9), (nu, reds)
    assert np.ptp(nu) > 1.0  # the parameters rest on the scales in different shares
    # A scale kept as stated (the touches', say) is certain: every count only grows, and
    # none falls below the one estimated scale's.
    views_only = std_dof(objective, x, dataclasses.replace(fit, touch_redundancy=0.0))
    assert np.all(views_only >= nu - 1e-9) and np.any(views_only > nu + 1.0)
    assert np.all(views_only >= min(reds[1:]) - 1e-9)
    # A combination's count: the parameters' own for unit directions.
    both = std_dof(objective, x, fit, directions=np.eye(12)[[0, 5]])
    np.testing.assert_allclose(both, nu[[0, 5]])


def test_no_estimated_scale_leaves_the_normal_quantile(clean):
    truth, one, _ = clean
    objective, x, fit = _fit_once(truth, one, 0.1, 0.3, 0.3, 6)
    none = dataclasses.replace(fit, view_redundancy=1.0, touch_redundancy=1.0)
    assert np.all(np.isinf(std_dof(objective, x, none)))


def test_the_paper_fit_reports_each_sigmas_degrees_of_freedom(paper_result):
    """Stage 2's corrections act on one side each: the views' on the pictures' residuals, the
    touches' on the touches': each σ has that side's count exactly. Stage 1's lie between."""
    diag, fit = paper_result.diagnostics, paper_result.stage2.noise
    dof2 = diag.stage2.std_dof
    for name in ("X1", "Y1", "theta1", "Sx1", "Sy1"):
        assert dof2[name] == pytest.approx(fit.view_redundancy, rel=1e-6)
    for name in ("X2", "Y2", "theta2", "Sx2", "Sy2"):
        assert dof2[name] == pytest.approx(fit.touch_redundancy, rel=1e-6)
    fit1, dof1 = paper_result.stage1.noise, diag.stage1.std_dof
    assert set(dof1) == {n for n, s in diag.stage1.std.items() if s is not None}
    reds = (fit1.view_redundancy, fit1.touch_redundancy)
    assert all(min(reds) - 1e-9 <= v <= sum(reds) + 1e-9 for v in dof1.values()), dof1
    # The verbose summary gives each σ its count.
    text = handeye_jax.format_summary(paper_result, verbose=True)
    for name, v in dof1.items():
        line = next(x for x in text.splitlines() if x.strip().startswith(f"{name} "))
        assert line.endswith(f"({v:.0f} dof)"), line
