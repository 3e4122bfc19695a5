"""How ``detect`` reads a picture that shows only part of the 3x3 grid: right, refused or wrong.

    python benchmarks/partial_match.py [--trials 800] [--seed 1]

Each trial views the paper's 3x3 snake through a random camera-like homography (turned by
-30 to 30 deg, scale 0.4 to 1.2, perspective terms within +-1.5e-4, blob noise 0.3 px), removes
one to four random landmarks and shuffles the rest, then asks
:func:`handeye_jax.vision._detect.match_blobs` which landmarks they are. A reading is *right* when
the landmarks and the blob of each are the true ones, *refused* when it raises (ambiguous or no
match), *wrong* otherwise. ``wrong`` must be 0: a refusal costs the operator a
``--landmarks``, a wrong reading a calibration.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from handeye_jax import snake_grid_px
from handeye_jax.vision import match_blobs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=800)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    layout = snake_grid_px()
    centred = layout - layout.mean(axis=0)
    rng = np.random.default_rng(args.seed)
    counts = {g: {"right": 0, "refused": 0, "wrong": 0} for g in range(1, 5)}
    start = time.perf_counter()
    for _ in range(args.trials):
        turn = np.radians(rng.uniform(-30, 30))
        scale, tilt = rng.uniform(0.4, 1.2), rng.uniform(-1.5e-4, 1.5e-4, 2)
        c, s = scale * np.cos(turn), scale * np.sin(turn)
        H = np.array([[c, -s, 320.0], [s, c, 240.0], [tilt[0], tilt[1], 1.0]])
        blobs = cv2.perspectiveTransform(centred[None], H)[0] + rng.normal(0, 0.3, (9, 2))
        g = int(rng.integers(1, 5))
        gone = set(rng.choice(9, g, replace=False).tolist())
        seen = np.array([m for m in range(9) if m not in gone])
        perm = rng.permutation(len(seen))
        try:
            landmarks, order = match_blobs(blobs[seen][perm], layout)
        except ValueError:
            counts[g]["refused"] += 1
            continue
        same_blobs = np.array_equal(perm[order], np.arange(len(seen)))
        right = np.array_equal(landmarks, seen) and same_blobs
        counts[g]["right" if right else "wrong"] += 1
    ms = (time.perf_counter() - start) / args.trials * 1e3
    print(f"{args.trials} trials (seed {args.seed}), {ms:.0f} ms a reading")
    print("missing  right  refused  wrong")
    for g, c in counts.items():
        print(f"{g:7d}  {c['right']:5d}  {c['refused']:7d}  {c['wrong']:5d}")
    total = {k: sum(c[k] for c in counts.values()) for k in ("right", "refused", "wrong")}
    print(f"  total  {total['right']:5d}  {total['refused']:7d}  {total['wrong']:5d}")


if __name__ == "__main__":
    main()
