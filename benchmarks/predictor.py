"""The NumPy predictor beside the JAX path: time per point for many points, in one process.

Target (issue 19): ``Predictor.hand_command`` at most 20 µs per point for 10,000 points,
in-process. The frames are the paper's HTM optimum (Table 7, with the notes' reading) on the
paper's rig, with a stage-2 correction near Table 10's; the points are random image points.
Both paths compute stage 2 (eq. 25), float64. The JAX path is jitted (compiled once before
timing); the predictor calls and the JAX calls alternate, so a slow phase of the shared
machine hits both alike.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from handeye_jax import (
    AffinePair,
    HTMModel,
    Predictor,
    Rig,
    Targets,
    compute_frames,
    hand_command,
)

TARGET_US = 20.0
PARAMS = {"xc": -2.05, "yc": 34.09, "alpha_c": 0.49, "beta_c": 0.48, "gamma_c": -0.73,
          "xt": 193.33, "yt": 31.62, "alpha_t": 1.5, "beta_t": -11.9, "gamma_t": -1.2,
          "xp": -0.46, "yp": -22.27}  # fmt: skip
AFFINE = {"X1": -0.1, "Y1": 0.003, "theta1": 0.03, "Sx1": 0.998, "Sy1": 1.02,
          "X2": 0.06, "Y2": -0.11, "theta2": -0.02, "Sx2": 1.017, "Sy2": 0.988}  # fmt: skip
CENTRES_MM = np.array([[326.5, -37.9], [325.9, -15.6]])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10_000, help="points per call (default 10000)")
    ap.add_argument("--rounds", type=int, default=50, help="timed calls of each path")
    ap.add_argument("--quick", action="store_true", help="1000 points, 5 rounds (a smoke test)")
    args = ap.parse_args(argv)
    n, rounds = (1000, 5) if args.quick else (args.points, args.rounds)

    with jax.enable_x64(True):
        model = HTMModel.from_dict(PARAMS)
        correction = AffinePair.from_dict(AFFINE)
        rig = Rig(617.7, 617.7, 316.5, 242.3, [320.0, -70.0, 290.0], 90.0, -1)
        predictor = Predictor.from_frames(compute_frames(model, rig, correction, CENTRES_MM))
        rng = np.random.default_rng(0)
        uv = rng.uniform([0.0, 0.0], [640.0, 480.0], (n, 2))
        depth = rng.uniform(150.0, 190.0, n)
        angle = rng.uniform(-180.0, 180.0, n)
        jitted = jax.jit(hand_command)
        args_jax = (model, rig, Targets(jnp.asarray(uv), jnp.asarray(depth), jnp.asarray(angle)))
        stage2 = {"correction": correction, "centres_mm": jnp.asarray(CENTRES_MM)}
        calls = {
            "numpy Predictor": lambda: predictor.hand_command(uv, depth, angle),
            "JAX path (jit)": lambda: np.asarray(jitted(*args_jax, **stage2)),
        }
        outs = {name: fn() for name, fn in calls.items()}  # compiles the JAX path
        times: dict[str, list[float]] = {name: [] for name in calls}
        for _ in range(rounds):
            for name, fn in calls.items():
                t0 = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t0)

    print(f"# NumPy predictor, {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores")
    print(f"command: python benchmarks/{Path(__file__).name} {' '.join(sys.argv[1:])}")
    print(
        f"{n} points per call, stage 2, {rounds} calls each, alternating; ms per call as "
        "median [min, max]\n"
    )
    print("| path | ms per call | µs per point | per point / 20 µs target |")
    print("|---|---|---|---|")
    for name, ts in times.items():
        ms = np.array(ts) * 1e3
        us = float(np.median(ms)) * 1e3 / n
        print(f"| {name} | {np.median(ms):.3f} [{ms.min():.3f}, {ms.max():.3f}] | {us:.3f} | "
              f"{us / TARGET_US:.4f} |")  # fmt: skip
    ratio = np.median(times["numpy Predictor"]) / np.median(times["JAX path (jit)"])
    diff = float(np.abs(outs["numpy Predictor"] - outs["JAX path (jit)"]).max())
    print(f"\nnumpy / JAX time: {ratio:.2f}; max |numpy − JAX| = {diff:.2e} mm")


if __name__ == "__main__":
    main()
