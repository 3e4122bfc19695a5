"""How many landmark dots ``detect`` finds in pictures taken from higher up, by dot size.

    python benchmarks/dots_by_height.py [--seeds 1 5] [--rises 0 40 80] [--dots 1 2]
                                        [--preset paper]

For each twin seed, the rig truth of ``handeye-jax simulate --seed S --dot-px D`` is drawn,
its capture pose raised by each rise (mm; the hand's x, y and angle unchanged), and the
picture rendered with the preset's imaging noise. The detector's blobs
(:func:`handeye_jax.vision._detect.find_blobs`, ``detect``'s defaults) are compared with the true
image points: a landmark is *found* when a blob lies within 1 px of it; blobs farther from
every landmark are *false*. The recommended acquisition takes pictures 40 and 80 mm above the
first: the paper's one-pixel dots shrink below the picture's noise there.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from handeye_jax import PRESETS, draw_truth
from handeye_jax.twin import render_capture
from handeye_jax.vision import find_blobs


def found(seed: int, rise_mm: float, dot_px: float, preset: str) -> tuple[int, int, np.ndarray]:
    """(landmarks found, false blobs, the found ones' centroid errors in px) in the picture
    from ``rise_mm`` above the capture."""
    truth = draw_truth(seed, dot_px=dot_px)
    raised = np.add(truth.capture_position_mm, [0.0, 0.0, rise_mm])
    truth = dataclasses.replace(truth, capture_position_mm=tuple(float(v) for v in raised))
    picture = render_capture(truth, PRESETS[preset].imaging, np.random.default_rng(seed))
    blobs = find_blobs(picture).image_px
    uv, _ = truth.project(truth.landmarks_tablet_px)
    if not len(blobs):
        return 0, 0, np.zeros(0)
    d = np.linalg.norm(blobs[:, None] - uv[None], axis=2)
    near = d.min(axis=0)
    return int((near < 1.0).sum()), int((d.min(axis=1) >= 1.0).sum()), near[near < 1.0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs=2, default=[1, 5], metavar=("FIRST", "LAST"))
    parser.add_argument("--rises", type=float, nargs="+", default=[0.0, 40.0, 80.0])
    parser.add_argument("--dots", type=float, nargs="+", default=[1.0, 2.0])
    parser.add_argument("--preset", choices=sorted(PRESETS), default="paper")
    args = parser.parse_args()
    seeds = range(args.seeds[0], args.seeds[1] + 1)
    print(f"preset {args.preset}, seeds {args.seeds[0]}-{args.seeds[1]}: landmarks found of 9 "
          "per seed (false blobs)")  # fmt: skip
    print("| dot, tablet px | rise, mm | found per seed | all found | centroid error RMS, px |")
    print("|---|---|---|---|---|")
    for dot in args.dots:
        for rise in args.rises:
            runs = [found(s, rise, dot, args.preset) for s in seeds]
            cells = " ".join(f"{f}" + (f" ({x})" if x else "") for f, x, _ in runs)
            whole = sum(f == 9 and x == 0 for f, x, _ in runs)
            errors = np.concatenate([e for _, _, e in runs])
            rms = f"{np.sqrt(np.mean(errors**2)):.3f}" if errors.size else "-"
            print(f"| {dot:g} | {rise:g} | {cells} | {whole} of {len(runs)} | {rms} |")


if __name__ == "__main__":
    main()
