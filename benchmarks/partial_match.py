"""How ``detect`` reads a picture that shows only part of the 3x3 grid: right, refused or wrong.

    python benchmarks/partial_match.py [--trials 10000] [--seed 1]

Each trial views the paper's 3x3 snake through a random camera-like homography (turned by
-30 to 30 deg, scale 0.4 to 1.2, perspective terms within +-1.5e-4, blob noise 0.3 px), removes
one to four random landmarks and shuffles the rest, then asks
:func:`handeye_jax.vision._detect.match_blobs` which landmarks they are. A reading is *right* when
the landmarks and the blob of each are the true ones, *refused* when it raises (ambiguous or no
match), *wrong* otherwise. ``wrong`` must be 0: a refusal costs the operator a
``--landmarks``, a wrong reading a calibration.

A refusal is *needed* when another reading fits the blobs about as well and is as plausible
a view: an unmirrored map of other landmarks (or of the same ones, paired otherwise) onto the
blobs, fitted by reprojection error, within the matcher's tolerance of the true reading's fit
(a tenth of the nearest two blobs' distance), its two scales within ``MAX_ANISOTROPY``, its
tablet x axis within ``PLAUSIBLE_TURN_DEG`` of +u, every landmark in front of the camera.
That search is this file's own (every ordered four of the nine landmarks mapped onto four
fixed blobs), not the matcher's. Any other refusal is *avoidable*. "rival <= 1 px" counts the
needed refusals whose rival fits within 1 px rms of the truth (no tolerance could tell them
apart). The refusals are also counted by the matcher's reason: "collinear" (no four blobs
span a quadrilateral), "no match", "ambiguous".
"""

from __future__ import annotations

import argparse
import itertools
import time

import cv2
import numpy as np

from handeye_jax import snake_grid_px
from handeye_jax.vision import MAX_ANISOTROPY, PLAUSIBLE_TURN_DEG, match_blobs

REASONS = {"collinear": ("quadrilateral", "collinear"), "no match": ("no part",),
           "ambiguous": ("as well as",)}  # fmt: skip


def view(layout: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The layout's landmarks as blobs in a random camera-like view, image px, ``(n, 2)``."""
    centred = layout - layout.mean(axis=0)
    turn = np.radians(rng.uniform(-30, 30))
    scale, tilt = rng.uniform(0.4, 1.2), rng.uniform(-1.5e-4, 1.5e-4, 2)
    c, s = scale * np.cos(turn), scale * np.sin(turn)
    H = np.array([[c, -s, 320.0], [s, c, 240.0], [tilt[0], tilt[1], 1.0]])
    return cv2.perspectiveTransform(centred[None], H)[0] + rng.normal(0, 0.3, (len(layout), 2))


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _fit(layout: np.ndarray, blobs: np.ndarray, which: np.ndarray):
    """Homography of ``layout[which]`` onto the blobs fitted by reprojection error: its rms
    residual (px), whether it is a plausible camera view, and the nearest landmark to each blob
    under it."""
    H, _ = cv2.findHomography(layout[which], blobs, 0)
    if H is None:
        return np.inf, False, None
    p = np.c_[layout, np.ones(len(layout))] @ H.T
    if p[:, 2].min() * p[:, 2].max() <= 0:  # the map folds the tablet through the horizon
        return np.inf, False, None
    mapped = p[:, :2] / p[:, 2:]
    rms = float(np.sqrt(np.mean(np.sum((mapped[which] - blobs) ** 2, axis=1))))
    nearest = np.linalg.norm(blobs[:, None] - mapped[None], axis=2).argmin(axis=1)
    # d(u, v)/d(x, y) at the layout's centre: columns, the pictures of tablet x and y
    q = H @ np.append(layout.mean(axis=0), 1.0)
    J = (H[:2, :2] - np.outer(q[:2] / q[2], H[2, :2])) / q[2]
    s = np.linalg.svd(J, compute_uv=False)
    turn = np.degrees(np.arctan2(J[1, 0], J[0, 0]))
    plausible = (np.linalg.det(J) > 0 and s[0] <= MAX_ANISOTROPY * s[1]
                 and abs(turn) < PLAUSIBLE_TURN_DEG)  # fmt: skip
    return rms, plausible, nearest


def rival(layout: np.ndarray, blobs: np.ndarray, truth: np.ndarray) -> float | None:
    """How much worse (rms, px) the best other plausible reading of the blobs fits than the
    truth, if one fits within the matcher's tolerance; else None. ``truth[j]`` is the landmark
    of ``blobs[j]``."""
    true_rms, _, _ = _fit(layout, blobs, truth)
    spacing = min(np.linalg.norm(a - b) for a, b in itertools.combinations(blobs, 2))

    def smallest_triangle(idx):
        p = blobs[list(idx)]
        return min(abs(_cross(p[b] - p[a], p[c] - p[a])) for a, b, c in
                   itertools.combinations(range(4), 3))  # fmt: skip

    # Four blobs that fix a homography: the four whose smallest triangle is largest.
    anchor = list(max(itertools.combinations(range(len(blobs)), 4), key=smallest_triangle))
    seen, best = set(), None
    for four in itertools.permutations(range(len(layout)), 4):
        H = cv2.getPerspectiveTransform(layout[list(four)].astype(np.float32),
                                        blobs[anchor].astype(np.float32))  # fmt: skip
        mapped = cv2.perspectiveTransform(layout[None], H)[0]
        which = np.linalg.norm(blobs[:, None] - mapped[None], axis=2).argmin(axis=1)
        key = tuple(which.tolist())
        if key in seen or len(set(key)) != len(key) or np.array_equal(which, truth):
            continue
        seen.add(key)
        rms, plausible, nearest = _fit(layout, blobs, which)
        if plausible and rms <= true_rms + 0.1 * spacing and np.array_equal(nearest, which):
            best = min(rms - true_rms, np.inf if best is None else best)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    layout = snake_grid_px()
    rng = np.random.default_rng(args.seed)
    kinds = ("right", "needed", "close", "avoidable", "wrong")
    counts = {g: dict.fromkeys(kinds, 0) for g in range(1, 5)}
    reasons = {g: dict.fromkeys(REASONS, 0) for g in range(1, 5)}
    seconds = 0.0
    for _ in range(args.trials):
        blobs = view(layout, rng)
        g = int(rng.integers(1, 5))
        gone = set(rng.choice(9, g, replace=False).tolist())
        seen = np.array([m for m in range(9) if m not in gone])
        perm = rng.permutation(len(seen))
        start = time.perf_counter()
        try:
            landmarks, order = match_blobs(blobs[seen][perm], layout)
        except ValueError as e:
            seconds += time.perf_counter() - start
            reason = next(r for r, words in REASONS.items() if any(w in str(e) for w in words))
            reasons[g][reason] += 1
            worse_px = rival(layout, blobs[seen][perm], seen[perm])
            counts[g]["needed"] += worse_px is not None
            counts[g]["close"] += worse_px is not None and worse_px <= 1.0
            counts[g]["avoidable"] += worse_px is None
            continue
        seconds += time.perf_counter() - start
        same_blobs = np.array_equal(perm[order], np.arange(len(seen)))
        right = np.array_equal(landmarks, seen) and same_blobs
        counts[g]["right" if right else "wrong"] += 1
    ms = seconds / args.trials * 1e3
    print(f"{args.trials} trials (seed {args.seed}), {ms:.1f} ms a reading")
    print("missing  right  refused  rival <= 1 px  avoidable  wrong  (refused: collinear, "
          "no match, ambiguous)")
    rows = [(f"{g:7d}", counts[g], reasons[g]) for g in counts]
    rows.append(("  total", {k: sum(c[k] for c in counts.values()) for k in kinds},
                 {k: sum(c[k] for c in reasons.values()) for k in REASONS}))
    for name, c, r in rows:
        print(f"{name}  {c['right']:5d}  {c['needed'] + c['avoidable']:7d}  {c['close']:13d}"
              f"  {c['avoidable']:9d}  {c['wrong']:5d}  ({r['collinear']}, {r['no match']}, "
              f"{r['ambiguous']})")


if __name__ == "__main__":
    main()
