"""Each σ's degrees of freedom (``std_dof``, Satterthwaite's), checked by Monte Carlo.

    python benchmarks/sigma_dof.py [--draws 150] [--twin 3] [--seed 1000] [--rounding]

A σ² the fit reports is a sum of the noise scales it estimated, each from its own redundancy;
over noise draws it scatters as a χ² with ``ν`` degrees of freedom would: its relative
variance is ``2/ν``. On a twin's rig and nine landmarks, its three pictures exact (with the
hand's heights: every parameter determined; one picture leaves two directions to the data's
noise, whose σ² then scatter without bound), each draw adds Gaussian noise of the ``paper``
model's form to the pictures (0.1 px, 0.3 mm) and the touches (0.3 mm in x and y, the
model's ratio in z), fits by Gauss–Newton with the scales alternated as the calibration does,
and takes every parameter's σ² and ``ν``. The table gives, per parameter, the draws' relative
variance of σ² against ``2/ν`` (mean ``ν``): the fit's σ², and the same with the Jacobian
taken at the true parameters (the scales' part, and the data's own through the
back-projection; not the optimum's wandering along a weakly determined direction).
``--rounding`` draws the touches' errors uniform, as the twins' are (the controller's whole
millimetres, the tablet's whole pixels): a uniform error's variance is estimated more
steadily than a Gaussian's (kurtosis 1.8, not 3), which the count, made for Gaussian noise,
does not know.
"""

from __future__ import annotations

import argparse
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from handeye_jax import (
    PRESETS,
    HTMModel,
    Stage1Objective,
    draw_truth,
    float64,
    simulate,
    vectorise_small_loops,
)
from handeye_jax.problem import (
    estimate_noise,
    get_noise_model,
    noise_objective,
    row_counts,
    std_dof,
    whitened_jacobian,
)

PAPER = get_noise_model("paper")
IMAGE_PX, DEPTH_MM, TOUCH_MM = 0.1, 0.3, 0.3
ROUNDS = 5
CAPTURES = 3


def dataset(captures: int, seed: int):
    """Twin ``seed``'s rig and landmarks, its pictures exact (``captures`` of them, with the
    hand's heights for more than one)."""
    truth = draw_truth(seed, dot_px=2.0)
    twin = simulate(truth, PRESETS["none"], seed, captures=captures, exact=True)
    return truth.htm(), twin.dataset


@eqx.filter_jit
def _gauss_newton(objective, x):
    r, J = objective.whitened(x), jax.jacfwd(objective.whitened)(x)
    return x - jnp.linalg.lstsq(J, r)[0]


def _touch_errors(rng, sd: float, shape, rounding: bool) -> np.ndarray:
    """Gaussian errors of σ ``sd``, or uniform ones of that σ (a rounding's: kurtosis 1.8)."""
    if rounding:
        return rng.uniform(-0.5, 0.5, shape) * sd * np.sqrt(12.0)
    return rng.normal(0.0, sd, shape)


def draw(truth, ds, rng, rounding: bool = False):
    """One noisy draw, fitted: each parameter's σ² and degrees of freedom (``rounding``: the
    touches' errors uniform, as the twins' are)."""
    exact = ds.observations()
    n = len(np.asarray(exact.hand_xy_mm))
    rows = np.arange(n) if exact.touch_index is None else np.asarray(exact.touch_index)
    m = int(rows.max()) + 1  # one error per touch, however many rows repeat it
    xy = np.sqrt(PAPER.touch_variance_mm2(exact.mm_per_tablet_px))
    z_sd = TOUCH_MM * np.sqrt(PAPER.hand_z_variance_mm2()) / xy  # the model's ratio
    noisy = (jnp.asarray(np.asarray(exact.image_px) + rng.normal(0, IMAGE_PX, (n, 2))),
             jnp.asarray(np.asarray(exact.depth_mm) + rng.normal(0, DEPTH_MM, n)),
             jnp.asarray(np.asarray(exact.hand_xy_mm)
                         + _touch_errors(rng, TOUCH_MM, (m, 2), rounding)[rows]))
    if exact.hand_z_mm is None:
        obs = eqx.tree_at(lambda o: (o.image_px, o.depth_mm, o.hand_xy_mm), exact, noisy)
    else:
        z = jnp.asarray(np.asarray(exact.hand_z_mm) + _touch_errors(rng, z_sd, m, rounding)[rows])
        obs = eqx.tree_at(lambda o: (o.image_px, o.depth_mm, o.hand_xy_mm, o.hand_z_mm),
                          exact, (*noisy, z))  # fmt: skip
    noise, x = PAPER, jnp.asarray(truth.to_vector())
    for _ in range(ROUNDS):  # the optimum and the scales, alternated as the fit does
        objective = noise_objective(Stage1Objective(HTMModel, obs), noise, truth, obs)
        for _ in range(3):
            x = _gauss_newton(objective, x)
        fit = estimate_noise(objective, x, noise, None, row_counts(obs))
        noise = fit.noise
    objective = noise_objective(Stage1Objective(HTMModel, obs), noise, truth, obs)
    J = np.asarray(whitened_jacobian(objective, x)[1])
    J0 = np.asarray(whitened_jacobian(objective, jnp.asarray(truth.to_vector()))[1])
    return (np.diag(np.linalg.pinv(J.T @ J, hermitian=True)),
            np.diag(np.linalg.pinv(J0.T @ J0, hermitian=True)), std_dof(objective, x, fit))


def main() -> None:
    vectorise_small_loops()  # as the command line does
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=150)
    ap.add_argument("--twin", type=int, default=3, help="the twin whose rig and landmarks")
    ap.add_argument("--seed", type=int, default=1000, help="the noise draws' seed")
    ap.add_argument("--rounding", action="store_true",
                    help="the touches' errors uniform (a rounding's), as the twins' are")
    args = ap.parse_args()
    t0 = time.perf_counter()
    rng = np.random.default_rng(args.seed)
    with float64():
        truth, ds = dataset(CAPTURES, args.twin)
        out = [draw(truth, ds, rng, args.rounding) for _ in range(args.draws)]
    s2, s2_truth, nu = (np.array(a) for a in zip(*out, strict=True))
    rel = s2.var(axis=0, ddof=1) / s2.mean(axis=0) ** 2
    # The same σ² from the Jacobian at the truth: the fit's own also moves with the optimum
    # where the data determine a direction weakly, which no count of the scales describes.
    rel0 = s2_truth.var(axis=0, ddof=1) / s2_truth.mean(axis=0) ** 2
    print(f"command: python benchmarks/sigma_dof.py --draws {args.draws} --twin {args.twin} "
          f"--seed {args.seed}" + (" --rounding" if args.rounding else ""))
    print(f"{args.draws} draws, {CAPTURES} captures, {time.perf_counter() - t0:.0f} s; "
          f"relative variance of σ² over the draws against 2/ν (its own standard error: "
          f"{np.sqrt(2 / (args.draws - 1)):.0%})\n")
    print("| parameter | mean ν | 2/ν | var(σ²)/E(σ²)² | ratio | at the true parameters | "
          "ratio |")
    print("|---|---|---|---|---|---|---|")
    for i, name in enumerate(HTMModel.param_names):
        pred = 2.0 / nu[:, i].mean()
        print(f"| {name} | {nu[:, i].mean():.0f} | {pred:.4f} | {rel[i]:.4f} | "
              f"{rel[i] / pred:.2f} | {rel0[i]:.4f} | {rel0[i] / pred:.2f} |")


if __name__ == "__main__":
    main()
